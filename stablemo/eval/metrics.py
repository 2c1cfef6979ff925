"""Text–motion metrics on evaluator embeddings (Guo et al. 2022; text-to-motion's `utils/metrics.py`).

All functions take numpy arrays of embeddings (N, E) and return plain floats, so the same code
scores the published Guo et al. evaluator and our own. Randomness (Diversity, MultiModality,
replications) comes from an explicit `np.random.Generator`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from scipy import linalg

from stablemo.errors import StableMoError

R_PRECISION_BATCH = 32
DIVERSITY_PAIRS = 300
MM_CAPTIONS = 100
MM_GENERATIONS = 30
MM_PAIRS = 10


def _as_2d(name: str, x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2:
        raise StableMoError(f"{name}: expected embeddings of shape (N, E), got {x.shape}")
    if not np.isfinite(x).all():
        raise StableMoError(f"{name}: embeddings contain NaN or Inf")
    return x


def pairwise_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distances (N, M) between rows of a (N, E) and b (M, E)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    # Direct differences (not the ‖a‖² − 2ab + ‖b‖² expansion): exact zeros for identical rows.
    return np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)


# ----------------------------------------------------------------------------- FID


def embedding_statistics(emb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean (E,) and unbiased covariance (E, E) of embeddings (N, E)."""
    emb = _as_2d("embeddings", emb)
    if emb.shape[0] < 2:
        raise StableMoError("embeddings: FID needs at least 2 samples")
    return emb.mean(0), np.cov(emb, rowvar=False)


def frechet_distance(mu1, sigma1, mu2, sigma2, eps: float = 1e-6) -> float:
    """‖μ₁ − μ₂‖² + tr(Σ₁ + Σ₂ − 2(Σ₁Σ₂)^½) between two Gaussians."""
    mu1, mu2 = np.atleast_1d(mu1), np.atleast_1d(mu2)
    sigma1, sigma2 = np.atleast_2d(sigma1), np.atleast_2d(sigma2)
    if mu1.shape != mu2.shape or sigma1.shape != sigma2.shape:
        raise StableMoError(f"FID: statistics shapes differ ({mu1.shape} vs {mu2.shape})")
    diff = mu1 - mu2
    covmean, _ = linalg.sqrtm(sigma1 @ sigma2, disp=False)
    if not np.isfinite(covmean).all():
        # Near-singular product: regularise both covariances, as the reference implementation does.
        offset = np.eye(sigma1.shape[0]) * eps
        covmean = linalg.sqrtm((sigma1 + offset) @ (sigma2 + offset))
    if np.iscomplexobj(covmean):
        # sqrtm of a PSD product is real up to round-off; large imaginary parts mean a real problem.
        if not np.allclose(np.diagonal(covmean).imag, 0, atol=1e-3):
            raise StableMoError(f"FID: complex matrix square root (max imag {np.abs(covmean.imag).max():.3g})")
        covmean = covmean.real
    return float(diff @ diff + np.trace(sigma1) + np.trace(sigma2) - 2.0 * np.trace(covmean))


def fid(emb_a: np.ndarray, emb_b: np.ndarray) -> float:
    """Fréchet distance between the Gaussian fits of two embedding sets."""
    return frechet_distance(*embedding_statistics(emb_a), *embedding_statistics(emb_b))


# ----------------------------------------------------------------------------- matching


@dataclass
class Matching:
    """R-precision top-1..k (fractions) and MM-Dist over the items scored."""

    r_precision: np.ndarray  # (k,)
    mm_dist: float
    num_items: int


def retrieval_ranks(text_emb: np.ndarray, motion_emb: np.ndarray,
                    batch_size: int = R_PRECISION_BATCH) -> tuple[np.ndarray, np.ndarray]:
    """Per pair, within consecutive batches of `batch_size` pairs: the rank of its motion among its
    batch's motions by distance to its text (0 = nearest; the number strictly closer) and that
    distance -> (ranks (n,), distances (n,)), n the whole batches' pairs. An incomplete last batch is
    dropped (the reference loader uses drop_last), so every item is ranked against exactly
    batch_size − 1 distractors. Per pair, so two ways of making the same motions can be compared
    pair by pair (a paired difference of R-precision)."""
    text_emb, motion_emb = _as_2d("text embeddings", text_emb), _as_2d("motion embeddings", motion_emb)
    if text_emb.shape != motion_emb.shape:
        raise StableMoError(f"R-precision: text {text_emb.shape} and motion {motion_emb.shape} differ")
    num_batches = text_emb.shape[0] // batch_size
    if num_batches == 0:
        raise StableMoError(f"R-precision: needs at least {batch_size} pairs, got {text_emb.shape[0]}")
    n = num_batches * batch_size
    texts = text_emb[:n].reshape(num_batches, batch_size, -1)
    motions = motion_emb[:n].reshape(num_batches, batch_size, -1)
    ranks, matched = [], []
    for t, m in zip(texts, motions):
        dist = pairwise_distances(t, m)  # (32, 32)
        ranks.append((dist < np.diagonal(dist)[:, None]).sum(1))
        matched.append(np.diagonal(dist))
    return np.concatenate(ranks), np.concatenate(matched)


def r_precision(text_emb: np.ndarray, motion_emb: np.ndarray, top_k: int = 3,
                batch_size: int = R_PRECISION_BATCH) -> Matching:
    """Text→motion retrieval within consecutive batches of `batch_size` pairs.

    Row i of text_emb matches row i of motion_emb. A top-k hit means the true motion is among
    the k nearest of its batch (retrieval_ranks, whose batches these are).
    """
    rank, matched = retrieval_ranks(text_emb, motion_emb, batch_size)
    hits = (rank[:, None] < np.arange(1, top_k + 1)[None, :]).sum(0)
    return Matching(r_precision=hits / len(rank), mm_dist=float(matched.sum() / len(rank)), num_items=len(rank))


def mm_dist(text_emb: np.ndarray, motion_emb: np.ndarray) -> float:
    """Mean Euclidean distance between matched text and motion embeddings (all rows)."""
    text_emb, motion_emb = _as_2d("text embeddings", text_emb), _as_2d("motion embeddings", motion_emb)
    return float(np.linalg.norm(text_emb - motion_emb, axis=1).mean())


# ----------------------------------------------------------------------------- diversity


def diversity(emb: np.ndarray, rng: np.random.Generator, num_pairs: int = DIVERSITY_PAIRS) -> float:
    """Mean distance between two random index sets of size num_pairs (drawn without replacement)."""
    emb = _as_2d("embeddings", emb)
    if emb.shape[0] <= num_pairs:
        raise StableMoError(f"Diversity: needs more than {num_pairs} samples, got {emb.shape[0]}")
    first = rng.choice(emb.shape[0], num_pairs, replace=False)
    second = rng.choice(emb.shape[0], num_pairs, replace=False)
    return float(np.linalg.norm(emb[first] - emb[second], axis=1).mean())


def multimodality(emb: np.ndarray, rng: np.random.Generator, num_pairs: int = MM_PAIRS) -> float:
    """emb: (C, G, E) — G generations per caption; mean distance of two random sets of num_pairs."""
    emb = np.asarray(emb, np.float64)
    if emb.ndim != 3:
        raise StableMoError(f"MultiModality: expected (captions, generations, E), got {emb.shape}")
    if emb.shape[1] < num_pairs:
        raise StableMoError(f"MultiModality: needs ≥ {num_pairs} generations per caption, got {emb.shape[1]}")
    first = rng.choice(emb.shape[1], num_pairs, replace=False)
    second = rng.choice(emb.shape[1], num_pairs, replace=False)
    return float(np.linalg.norm(emb[:, first] - emb[:, second], axis=2).mean())


# ----------------------------------------------------------------------------- replications


@dataclass
class Interval:
    mean: float
    half_width: float  # 95% interval: mean ± half_width
    values: list[float]

    def __str__(self) -> str:
        return f"{self.mean:.3f}±{self.half_width:.3f}"

    def to_dict(self) -> dict:
        return {"mean": self.mean, "conf95": self.half_width, "values": list(self.values)}


def replication_interval(values: Sequence[float]) -> Interval:
    """mean ± 1.96·σ/√R over R replications, σ the population standard deviation (ddof=0)."""
    v = np.asarray(values, np.float64).ravel()
    if v.size == 0:
        raise StableMoError("replications: no values")
    return Interval(mean=float(v.mean()), half_width=float(1.96 * v.std() / np.sqrt(v.size)),
                    values=[float(x) for x in v])


# ----------------------------------------------------------------------------- AITS


def average_inference_time(generate_one: Callable[[str, int], object], texts: Sequence[str],
                           lengths: Sequence[int], warmup: int = 1,
                           synchronize: Callable[[], None] | None = None,
                           reset: Callable[[], None] | None = None) -> float:
    """AITS: mean seconds per sentence, batch size 1, model and data loading excluded.

    `generate_one(text, length)` must run the full text→motion path for one sentence. The first
    `warmup` calls (kernel/JIT warm-up, text-encoder load) are not timed. `synchronize` (e.g.
    torch.cuda.synchronize) is called before each clock read so asynchronous GPUs are timed fully.
    `reset` runs untimed before every timed sentence, e.g. a pipeline's `clear_text_caches(keep_null=True)`,
    so that each sentence pays for its own text encoding whatever was timed before it in the process.
    """
    methods = {"": (generate_one, reset)}
    return average_inference_times(methods, texts, lengths, warmup, synchronize)[""]


def pipeline_method(pipe, steps: int, cfg: float, sampler: str | None = None, seed: int = 0,
                    controls: dict | None = None):
    """(generate_one, reset) of a stablemo Pipeline for average_inference_time(s): one sentence at
    its length clamped to the bundle's range, and a reset that clears the prompt caches but keeps
    the null prompt (a property of the model, encoded once per pipeline). controls: text ->
    JointControl, for the AITS of controlled generation."""
    def generate_one(text: str, length: int):
        control = None if controls is None else controls.get(text)
        return pipe.generate([text], [min(max(length, pipe.min_length), pipe.max_length)], steps=steps, cfg=cfg,
                             sampler=sampler, seed=seed, control=control)

    return generate_one, lambda: pipe.clear_text_caches(keep_null=True)


def average_inference_times(methods: dict[str, tuple[Callable[[str, int], object], Callable[[], None] | None]],
                            texts: Sequence[str], lengths: Sequence[int], warmup: int = 1,
                            synchronize: Callable[[], None] | None = None) -> dict[str, float]:
    """AITS of several methods {name: (generate_one, reset)} measured side by side.

    Sentence by sentence, every method runs in turn (round-robin), so a machine whose speed drifts
    during the run (shared cores, clocks) slows all of them alike and their ratios stay meaningful.
    Warm-up, `synchronize` and `reset` as in `average_inference_time`.
    """
    if len(texts) != len(lengths) or not texts:
        raise StableMoError("AITS: texts and lengths must be non-empty and of equal size")
    sync = synchronize or (lambda: None)
    for generate_one, _ in methods.values():
        for i in range(min(warmup, len(texts))):
            generate_one(texts[i], int(lengths[i]))
    totals = dict.fromkeys(methods, 0.0)
    for text, length in zip(texts, lengths):
        for name, (generate_one, reset) in methods.items():
            if reset is not None:
                reset()
            sync()
            start = time.perf_counter()
            generate_one(text, int(length))
            sync()
            totals[name] += time.perf_counter() - start
    return {name: total / len(texts) for name, total in totals.items()}
