"""R@3 of the very motions the behaviour checks read, to show what retrieval misses.

Each motion is a top-3 hit when its own text's motion is among the 3 nearest of a batch of
R_PRECISION_BATCH (32) distinct prompts in the text-motion evaluator's space (stablemo.eval.metrics'
R-precision, item by item). Features are extracted from the joints the checks measured
(stablemo.motion.joints_to_features), so both see one motion. Batches: within each group of items
with distinct texts (one seed at one length), the items in a fixed random order cut into blocks of
32; the last, short block is topped up with the items before it, which are not scored twice.
"""

from __future__ import annotations

import numpy as np
import torch

from stablemo.eval.evaluate import embed_motions, embed_texts
from stablemo.eval.metrics import R_PRECISION_BATCH, pairwise_distances
from stablemo.motion.features import joints_to_features

TOP_K = 3


def blocks(group: list[int], rng: np.random.Generator, size: int = R_PRECISION_BATCH) -> list[tuple[list[int], list[int]]]:
    """(batch, scored) index lists covering `group` once each; [] when it is smaller than a batch."""
    if len(group) < size:
        return []
    order = [group[i] for i in rng.permutation(len(group))]
    out = [(order[s:s + size], order[s:s + size]) for s in range(0, len(order) - size + 1, size)]
    done = len(out) * size
    if done < len(order):
        out.append((order[-size:], order[done:]))
    return out


def top3_hits(evaluator, texts: list[str], joints: list[np.ndarray], groups: list[list[int]],
              seed: int = 0) -> list[bool | None]:
    """Per item: a top-3 hit (True/False), or None where its group is smaller than a batch."""
    features = [torch.from_numpy(joints_to_features(np.asarray(j, dtype=np.float32))) for j in joints]
    text_emb = embed_texts(evaluator, list(texts), [[] for _ in texts], 64)
    motion_emb = embed_motions(evaluator, features, 64)
    hits: list[bool | None] = [None] * len(texts)
    rng = np.random.default_rng(seed)
    for group in groups:
        for batch, scored in blocks(group, rng):
            dist = pairwise_distances(text_emb[batch], motion_emb[batch])  # (32, 32): text i to motion j
            rank = (dist < np.diagonal(dist)[:, None]).sum(1)  # motions strictly nearer than the true one
            for k, item in enumerate(batch):
                if item in scored:
                    hits[item] = bool(rank[k] < TOP_K)
    return hits


__all__ = ["TOP_K", "blocks", "top3_hits"]
