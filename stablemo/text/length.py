"""How long should a motion be? A small predictor from the prompt's sentence embedding to a
distribution over lengths, so a motion asked for without a length gets the text's length.

The synthetic actions have nearly one length each (a double jump ~3 s), so the models learnt that
length implies count: "a person jumps in place twice" at a fixed 6 s jumped four times. Following the
idea of T2M's length estimator (Guo et al., CVPR 2022: a categorical distribution over 4-frame length
bins from the text, which MoMask uses at inference), a bundle can carry `length.safetensors`: a
two-layer network from the sentence embedding of the bundle's frozen text encoder
(stablemo.text.familiar.sentence_embeddings, the same one the familiarity check uses) to length bins
of `width` frames between `min_frames` and `max_frames`. Inference takes the mode, the middle of the
most likely `window` bins in a row (window 3 on the demo data: closer to the true length on the val
split than the single most likely bin): a prompt always gets the same length, whatever its seed, and
no draw from a wide distribution's tail picks the length of another count. Trained and measured by scripts/text/length_predictor.py.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from torch import nn

from stablemo.errors import StableMoError
from stablemo.text.familiar import sentence_embeddings

FILE = "length.safetensors"  # in a bundle: hidden.{weight,bias}, out.{weight,bias} (float32)
ENTRY = "length_predictor"  # its config.json entry
TENSORS = ("hidden.weight", "hidden.bias", "out.weight", "out.bias")


@dataclass(frozen=True)
class LengthBins:
    """Bin k holds the lengths [min_frames + k * width, min_frames + (k + 1) * width), the last one
    ending at max_frames; a length outside [min_frames, max_frames] counts as the nearest bin."""

    min_frames: int
    max_frames: int
    width: int

    def __post_init__(self):
        if not (isinstance(self.width, int) and isinstance(self.min_frames, int) and isinstance(self.max_frames, int)
                and self.width >= 1 and 1 <= self.min_frames <= self.max_frames):
            raise StableMoError(f"length bins: need whole numbers 1 <= min_frames <= max_frames and width >= 1, got "
                                f"{self.min_frames}, {self.max_frames}, {self.width}")

    @property
    def count(self) -> int:
        return (self.max_frames - self.min_frames) // self.width + 1

    def of(self, frames: torch.Tensor) -> torch.Tensor:
        """(N,) lengths -> (N,) bin indices (long)."""
        frames = frames.long().clamp(self.min_frames, self.max_frames)
        return (frames - self.min_frames) // self.width

    def frames(self, bins: torch.Tensor) -> torch.Tensor:
        """(N,) bin indices -> (N,) the middle length of each bin (long), within max_frames."""
        return (self.min_frames + bins.long() * self.width + self.width // 2).clamp(max=self.max_frames)


@dataclass(frozen=True)
class LengthFit:
    """Training settings; their values live in configs/text/length_predictor.yaml."""

    bin_frames: int
    hidden: int
    dropout: float
    lr: float
    weight_decay: float
    batch_size: int
    max_epochs: int
    patience: int  # epochs without a better val loss before stopping
    seed: int
    windows: tuple[int, ...]  # the mode's windows (odd bin counts) to choose from on the val split


class _LengthNet(nn.Module):
    def __init__(self, dim: int, hidden: int, bins: int, dropout: float = 0.0):
        super().__init__()
        self.hidden, self.out, self.drop = nn.Linear(dim, hidden), nn.Linear(hidden, bins), nn.Dropout(dropout)

    def forward(self, emb: torch.Tensor) -> torch.Tensor:  # (N, D) -> (N, K) logits
        return self.out(self.drop(nn.functional.gelu(self.hidden(emb))))


class LengthPredictor:
    """Sentence embedding (N, D) -> logits over `bins.count` length bins."""

    def __init__(self, tensors: dict[str, torch.Tensor], bins: LengthBins, encoder: str, window: int = 1):
        if not (isinstance(window, int) and window >= 1 and window % 2 == 1):
            raise StableMoError(f"length predictor: window must be an odd whole number of bins >= 1, got {window!r}")
        hidden, dim = tensors["hidden.weight"].shape
        self.net = _LengthNet(dim, hidden, tensors["out.weight"].shape[0]).eval().requires_grad_(False)
        self.net.load_state_dict({k: tensors[k].float() for k in TENSORS})
        self.bins, self.encoder, self.window = bins, encoder, window

    @property
    def dim(self) -> int:
        return self.net.hidden.in_features

    def probabilities(self, embeddings: torch.Tensor) -> torch.Tensor:
        """(N, D) unit sentence embeddings -> (N, K) probabilities over the bins."""
        with torch.inference_mode():
            return self.net(embeddings.float()).softmax(-1)

    def mode_bins(self, embeddings: torch.Tensor) -> torch.Tensor:
        """(N, D) -> (N,) the middle bin of the most likely `window` bins in a row (long)."""
        probs = self.probabilities(embeddings)[:, None]  # (N, 1, K)
        ones = torch.ones(1, 1, self.window)
        return nn.functional.conv1d(probs, ones, padding=self.window // 2)[:, 0].argmax(-1)

    def mode_frames(self, embeddings: torch.Tensor) -> torch.Tensor:
        """(N, D) -> (N,) the mode's length in frames (the middle of its bin; long)."""
        return self.bins.frames(self.mode_bins(embeddings))

    def quantile_frames(self, embeddings: torch.Tensor, q: float) -> torch.Tensor:
        """(N, D) -> (N,) the end of the first bin where the predicted lengths' distribution reaches
        `q` (long, within max_frames): how long such a text's motion is at most, as a rule."""
        cdf = self.probabilities(embeddings).cumsum(-1)  # (N, K)
        bins = (cdf < q).sum(-1).clamp(max=self.bins.count - 1)
        return (self.bins.min_frames + (bins + 1) * self.bins.width).clamp(max=self.bins.max_frames)

    def predict(self, encoder, texts: list[str]) -> list[int]:
        """One length in frames per text (the mode), from `encoder`'s sentence embeddings."""
        return [int(n) for n in self.mode_frames(sentence_embeddings(encoder, list(texts)))]

    def measure(self, embeddings: torch.Tensor, frames: torch.Tensor) -> dict:
        """Held-out numbers: share of modes within one bin of the true length's bin, median absolute
        error in frames (mode length vs true length), mean negative log-likelihood of the true bin."""
        probs = self.probabilities(embeddings)
        true = self.bins.of(frames)
        mode = self.mode_bins(embeddings)
        nll = -probs.gather(1, true[:, None]).clamp_min(1e-12).log().mean()
        err = (self.bins.frames(mode) - frames.long()).abs().float()
        return {"n": len(frames), "within_one_bin": round(float(((mode - true).abs() <= 1).float().mean()), 4),
                "median_abs_error_frames": float(err.median()), "nll": round(float(nll), 4)}

    # ---- a bundle's file ------------------------------------------------------------------------

    def write(self, folder: str | Path, report: dict | None = None) -> dict:
        """Writes FILE into a bundle folder (atomically); returns the config entry (`report`, e.g. the
        held-out numbers, is kept in it for the reader)."""
        from safetensors.torch import save

        from stablemo.io import write_bytes

        state = self.net.state_dict()
        write_bytes(Path(folder) / FILE, save({k: state[k].contiguous() for k in TENSORS}))
        return {"file": FILE, "encoder": self.encoder, **asdict(self.bins), "window": self.window, **(report or {})}

    @classmethod
    def load(cls, folder: str | Path, entry: dict, source: str = "config.json") -> LengthPredictor:
        from safetensors import safe_open

        path = Path(folder) / FILE
        keys = ("min_frames", "max_frames", "width", "window")
        if not isinstance(entry, dict) or not all(isinstance(entry.get(k), int) for k in keys) \
                or not isinstance(entry.get("encoder"), str):
            raise StableMoError(f"{source}: '{ENTRY}' must be an object with the text encoder's name and whole "
                                f"numbers {', '.join(keys)}")
        try:
            bins = LengthBins(*(entry[k] for k in keys[:3]))
        except StableMoError as err:
            raise StableMoError(f"{source}: '{ENTRY}': {err}") from None
        if not path.is_file():
            raise StableMoError(f"{source}: '{ENTRY}' names {FILE}, which the bundle does not hold")
        try:
            with safe_open(str(path), framework="pt") as f:
                tensors = {k: f.get_tensor(k) for k in TENSORS if k in f.keys()}
        except Exception as err:  # safetensors raises its own error types for a corrupt header
            raise StableMoError(f"{path}: unreadable safetensors file ({' '.join(str(err).split())})") from None
        shapes = {k: tuple(v.shape) for k, v in tensors.items()}
        if len(tensors) < len(TENSORS) or len(shapes["hidden.weight"]) != 2 \
                or shapes["out.weight"] != (bins.count, shapes["hidden.weight"][0]) \
                or shapes["hidden.bias"] != shapes["hidden.weight"][:1] or shapes["out.bias"] != (bins.count,):
            raise StableMoError(f"{path}: expected tensors {', '.join(TENSORS)} of a (D -> H -> {bins.count} bins) "
                                f"network, found {shapes}")
        if not all(v.is_floating_point() and torch.isfinite(v).all() for v in tensors.values()):
            raise StableMoError(f"{path}: the length predictor's weights hold NaN/Inf; write it again "
                                "(scripts/text/length_predictor.py)")
        try:
            return cls(tensors, bins, entry["encoder"], entry["window"])
        except StableMoError as err:
            raise StableMoError(f"{source}: '{ENTRY}': {err}") from None

    # ---- training -------------------------------------------------------------------------------

    @classmethod
    def fit(cls, train: tuple[torch.Tensor, torch.Tensor], val: tuple[torch.Tensor, torch.Tensor],
            bins: LengthBins, encoder: str, settings: LengthFit,
            log=None) -> tuple[LengthPredictor, dict]:
        """Cross-entropy on (embeddings (N, D), lengths (N,)) pairs of the train split, the epoch of
        the lowest val loss kept (stopping `patience` epochs after it), then the mode's window of
        `settings.windows` whose modes fall within one bin of the val lengths most often (the
        smallest of equals). Deterministic for a seed: the
        initial weights and dropout draw from torch's generator seeded inside a forked random state,
        the batch order from a generator of its own. Returns the predictor and {"epoch": kept epoch,
        "epochs": epochs run, "window": the mode's window}."""
        (x, frames), (vx, vframes) = train, val
        y, vy = bins.of(frames), bins.of(vframes)
        with torch.random.fork_rng(devices=[]):  # the caller's random state is left as it was
            torch.manual_seed(settings.seed)
            net = _LengthNet(x.shape[1], settings.hidden, bins.count, settings.dropout)
            order = torch.Generator().manual_seed(settings.seed)
            opt = torch.optim.AdamW(net.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)
            best, best_epoch, epoch = float("inf"), 0, 0
            best_state = {k: v.clone() for k, v in net.state_dict().items()}
            for epoch in range(1, settings.max_epochs + 1):
                net.train()
                for idx in torch.randperm(len(x), generator=order).split(settings.batch_size):
                    loss = nn.functional.cross_entropy(net(x[idx]), y[idx])
                    opt.zero_grad()
                    loss.backward()
                    opt.step()
                net.eval()
                with torch.no_grad():
                    val_loss = float(nn.functional.cross_entropy(net(vx), vy))
                if not math.isfinite(val_loss):
                    raise StableMoError(f"length predictor: the val loss is {val_loss} at epoch {epoch}; "
                                        "nothing written")
                if val_loss < best:
                    best, best_epoch = val_loss, epoch
                    best_state = {k: v.clone() for k, v in net.state_dict().items()}
                if log and epoch % 20 == 0:
                    log(f"epoch {epoch}: train loss {float(loss.detach()):.3f}, val loss {val_loss:.3f} "
                        f"(best {best:.3f} at {best_epoch})")
                if epoch - best_epoch >= settings.patience:
                    break
        scored = []
        for window in sorted(settings.windows):
            predictor = cls(best_state, bins, encoder, window)
            scored.append((-predictor.measure(vx, vframes)["within_one_bin"], window, predictor))
        _, window, predictor = min(scored, key=lambda row: row[:2])
        return predictor, {"epoch": best_epoch, "epochs": epoch, "window": window}


__all__ = ["ENTRY", "FILE", "LengthBins", "LengthFit", "LengthPredictor"]
