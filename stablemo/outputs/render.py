"""Stick-figure views of motions: GIF/MP4 animation, PNG strip of frames, PNG contact sheet.

A fixed orthographic camera (2.5D: 3D points projected once per frame onto a 2D matplotlib canvas,
no mplot3d) looks at the figure from the front, 35° towards its left side, 20° above. The floor (y = 0) gets a
grid, the root's path is traced on it (faint in full, solid up to the current frame), and the
skeleton casts a flat shadow so contact with the floor is visible. Left limbs are blue, right limbs
red, the spine grey. Input joints are (T, J, 3), y up, in the skeleton's units.

`stablemo render FILE.npy --out FILE.gif [--frames] [--skeleton humanml3d|kit] [--fps N] [--title T]`
accepts features (T, D) or joints (T, J, 3).
"""

from __future__ import annotations

import itertools
import shutil
import subprocess
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from stablemo.errors import StableMoError
from stablemo.io import atomic_open, atomic_path, load_npy
from stablemo.motion import (
    Skeleton,
    features_to_joints,
    get_skeleton,
    skeleton_for_shape,
)
from stablemo.motion.plausible import check_fps, check_joints_extent

COLOURS = {"left": "#1f6fd1", "right": "#d62f2f", "center": "#444444"}
SHADOW = "#9a9a9a"
GRID = "#c8c8c8"
PATH = "#2a9d5c"
TARGET = "#e08a00"  # joint-control targets
AZIMUTH_DEG, ELEVATION_DEG = 35.0, 20.0
MAX_GRID_LINES = 40  # floor-grid lines across each axis, at most
DPI = 80


# --------------------------------------------------------------------------- geometry


def _camera(azimuth_deg: float = AZIMUTH_DEG, elevation_deg: float = ELEVATION_DEG) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthographic camera basis (right, up, towards-viewer). Azimuth 0 = in front of a body facing +z."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    back = np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    forward = -back
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return right, up, back


class _View:
    """Projection of one motion: fixed camera, floor grid and bounds fitted to the whole clip."""

    def __init__(self, joints: np.ndarray, skeleton: Skeleton):
        self.skeleton = skeleton
        self.right, self.up, self.back = _camera()
        unit = 1000.0 if skeleton.units == "mm" else 1.0
        xz = joints[:, :, [0, 2]].reshape(-1, 2)
        margin = 0.5 * unit
        spacing = _grid_spacing(float((xz.max(0) - xz.min(0)).max()) + 2 * margin, unit)
        lo = np.floor((xz.min(0) - margin) / spacing) * spacing
        hi = np.ceil((xz.max(0) + margin) / spacing) * spacing
        self.grid = []  # list of (2, 2) projected segments
        for x in np.arange(lo[0], hi[0] + spacing / 2, spacing):
            self.grid.append(self.project(np.array([[x, 0.0, lo[1]], [x, 0.0, hi[1]]])))
        for z in np.arange(lo[1], hi[1] + spacing / 2, spacing):
            self.grid.append(self.project(np.array([[lo[0], 0.0, z], [hi[0], 0.0, z]])))
        pts = np.concatenate([self.project(joints.reshape(-1, 3)), np.concatenate(self.grid)])
        lo2, hi2 = pts.min(0), pts.max(0)
        pad = 0.03 * (hi2 - lo2).max()
        self.xlim = (lo2[0] - pad, hi2[0] + pad)
        self.ylim = (lo2[1] - pad, hi2[1] + pad)
        # height / width of the drawing, kept within sane bounds; axes use equal scale
        self.aspect = float(np.clip((self.ylim[1] - self.ylim[0]) / (self.xlim[1] - self.xlim[0]), 0.45, 1.6))
        self.bones = [(chain, COLOURS[skeleton.side_of_chain(i)]) for i, chain in enumerate(skeleton.kinematic_chains)]

    def project(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) -> (..., 2) screen coordinates."""
        return np.stack([points @ self.right, points @ self.up], axis=-1)

    def depth(self, points: np.ndarray) -> np.ndarray:
        return points @ self.back  # larger = nearer the viewer


def _grid_spacing(extent: float, unit: float) -> float:
    """Floor-grid spacing: 0.5 m, or a wider 1-2-5 step so that at most MAX_GRID_LINES lines cross an
    axis: the drawing's cost is bounded by the image, not by how far the motion travels."""
    spacing, factors = 0.5 * unit, itertools.cycle((2.0, 2.0, 2.5))  # 0.5, 1, 2, 5, 10, 20, 50 ... m
    while extent / spacing > MAX_GRID_LINES:
        spacing *= next(factors)
    return spacing


def _check_joints(joints: np.ndarray, skeleton: Skeleton, name: str = "joints") -> np.ndarray:
    arr = np.asarray(joints)
    if arr.ndim != 3 or arr.shape[1:] != (skeleton.num_joints, 3):
        raise StableMoError(f"{name}: expected joints of shape (T, {skeleton.num_joints}, 3) for skeleton {skeleton.name}, got {arr.shape}")
    if len(arr) == 0:
        raise StableMoError(f"{name}: no frames")
    if not np.all(np.isfinite(arr)):
        raise StableMoError(f"{name}: contains NaN or Inf")
    check_joints_extent(arr, skeleton, skeleton.fps, name)
    return arr.astype(np.float64)


# --------------------------------------------------------------------------- drawing


class _Panel:
    """Artists of one axes showing one motion; `show(t)` moves them to frame t."""

    def __init__(self, ax, joints: np.ndarray, view: _View, title: str | None, show_time: bool, fps: float,
                 targets: "tuple[np.ndarray, np.ndarray] | None" = None):
        from matplotlib.collections import LineCollection

        self.ax, self.joints, self.view, self.fps, self.show_time = ax, joints, view, fps, show_time
        ax.set_xlim(*view.xlim)
        ax.set_ylim(*view.ylim)
        ax.set_aspect("equal")
        ax.set_axis_off()
        ax.add_collection(LineCollection(view.grid, colors=GRID, linewidths=0.7, zorder=0))
        path = joints[:, 0].copy()
        path[:, 1] = 0.0
        self.path2d = view.project(path)
        ax.plot(*self.path2d.T, color=PATH, alpha=0.25, lw=1.0, zorder=1)
        (self.path_done,) = ax.plot([], [], color=PATH, lw=1.8, zorder=2)
        self.shadows = [ax.plot([], [], color=SHADOW, lw=2.0, alpha=0.6, solid_capstyle="round", zorder=3)[0] for _ in view.bones]
        self.lines = [
            ax.plot([], [], color=colour, lw=2.6, solid_capstyle="round", zorder=10)[0] for _, colour in view.bones
        ]
        (self.head,) = ax.plot([], [], "o", color=COLOURS["center"], ms=5, zorder=20)
        # the head is the end of the first centre chain (the spine)
        self.head_joint = next(c for c, colour in view.bones if colour == COLOURS["center"])[-1]
        # joint targets (joint control): every target faint, the current frame's bold
        self.targets = None
        if targets is not None:
            positions, mask = targets  # (T, J, 3), (T, J) bool
            self.targets = (positions, mask)
            pts = view.project(positions[mask])
            ax.plot(pts[:, 0], pts[:, 1], ".", color=TARGET, ms=2.5, alpha=0.35, zorder=4)
            (self.target_now,) = ax.plot([], [], "x", color=TARGET, ms=7, mew=2.0, zorder=30)
        if title:
            ax.set_title(title, fontsize=9)
        self.text = ax.text(0.02, 0.02, "", transform=ax.transAxes, fontsize=7, color="#555555") if show_time else None

    def show(self, t: int) -> None:
        pose = self.joints[t]
        flat = pose.copy()
        flat[:, 1] = 0.0
        pose2d, flat2d = self.view.project(pose), self.view.project(flat)
        for (chain, _), line, shadow in zip(self.view.bones, self.lines, self.shadows):
            idx = list(chain)
            line.set_data(pose2d[idx, 0], pose2d[idx, 1])
            # nearer chains on top
            line.set_zorder(10 + float(self.view.depth(pose[idx]).mean()) / (1e3 if self.view.skeleton.units == "mm" else 1))
            shadow.set_data(flat2d[idx, 0], flat2d[idx, 1])
        self.head.set_data([pose2d[self.head_joint, 0]], [pose2d[self.head_joint, 1]])
        self.path_done.set_data(self.path2d[: t + 1, 0], self.path2d[: t + 1, 1])
        if self.targets is not None:
            positions, mask = self.targets
            now = self.view.project(positions[t][mask[t]]) if t < len(mask) and mask[t].any() else np.zeros((0, 2))
            self.target_now.set_data(now[:, 0], now[:, 1])
        if self.text is not None:
            self.text.set_text(f"frame {t}  {t / self.fps:.2f} s")


def _figure(width_in: float, height_in: float):
    # Agg canvas without pyplot: no global state, no display needed, thread-safe enough for us
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def _rgb(fig) -> np.ndarray:
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()


def _animation_figure(joints: np.ndarray, skeleton: Skeleton, fps: float, title: str | None, targets=None):
    """(figure, show(t)): one figure whose panel is redrawn for frame t."""
    view = _View(joints, skeleton)
    head = 0.35 if title else 0.0  # inches reserved for the title
    fig = _figure(5.6, 5.6 * view.aspect + head)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0 - head / fig.get_figheight()))
    panel = _Panel(ax, joints, view, None, True, fps, targets)
    if title:
        fig.suptitle(title, fontsize=10, y=0.985)
    return fig, panel.show


def _animation_frames(joints: np.ndarray, skeleton: Skeleton, fps: float, title: str | None,
                      targets=None) -> Iterator[np.ndarray]:
    fig, show = _animation_figure(joints, skeleton, fps, title, targets)
    for t in range(len(joints)):
        show(t)
        yield _rgb(fig)


def _gif_palette():
    from matplotlib.colors import to_rgb
    from PIL import Image

    bases = [*COLOURS.values(), SHADOW, GRID, PATH, TARGET, "#555555", "#000000"]
    colours = []
    for base in bases:
        rgb = np.array(to_rgb(base))
        colours += [rgb * (1 - a) + a for a in np.linspace(0.0, 0.9, 12)]  # blends towards white
    colours.append(np.ones(3))
    flat = (np.clip(np.array(colours), 0, 1) * 255).round().astype(np.uint8).reshape(-1)
    img = Image.new("P", (1, 1))
    img.putpalette(flat.tolist() + [255] * (768 - len(flat)))
    return img


def _write_gif(frames: Iterator[np.ndarray], path: Path, fps: float) -> None:
    from PIL import Image

    # One fixed palette for the whole clip: our drawing colours and their anti-aliasing blends
    # towards white. Much faster than per-frame adaptive palettes, exact limb colours, and unchanged
    # pixels stay identical so Pillow's frame differencing keeps the file small.
    palette = _gif_palette()
    images = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
    duration = max(int(round(1000.0 / fps)), 10)  # GIF time unit is 10 ms
    with atomic_open(path) as f:
        images[0].save(f, format="GIF", save_all=True, append_images=images[1:], duration=duration, loop=0, optimize=False)


def _write_mp4(joints: np.ndarray, skeleton: Skeleton, fps: float, title: str | None, path: Path,
               targets=None) -> None:
    """H.264 through matplotlib's FFMpegWriter (it pipes the figure's frames to ffmpeg and keeps the
    frame size even, as yuv420p needs)."""
    from matplotlib.animation import FFMpegWriter

    fig, show = _animation_figure(joints, skeleton, fps, title, targets)
    writer = FFMpegWriter(fps=fps, codec="h264", extra_args=["-pix_fmt", "yuv420p", "-loglevel", "error"])
    with atomic_path(path) as tmp:  # ffmpeg needs a file name: an exclusive temp file's
        try:
            with writer.saving(fig, str(tmp), dpi=fig.dpi):
                for t in range(len(joints)):
                    show(t)
                    writer.grab_frame()
        except (OSError, subprocess.CalledProcessError) as err:
            raise StableMoError(f"{path}: ffmpeg failed ({err})") from None


def render_animation(
    joints: np.ndarray,
    path: str | Path,
    skeleton: Skeleton | str = "humanml3d",
    fps: float | None = None,
    title: str | None = None,
    targets: "tuple[np.ndarray, np.ndarray] | None" = None,
) -> Path:
    """Write an animation of joints (T, J, 3); the format follows the suffix (.gif, or .mp4 with
    ffmpeg). fps defaults to the skeleton's (20 for HumanML3D). targets: joint-control targets
    (positions (T, J, 3), mask (T, J)) drawn as points. Atomic: no half-written file."""
    skel = get_skeleton(skeleton)
    path = Path(path)
    arr = _check_joints(joints, skel)
    targets = _check_targets(targets, arr)
    fps = check_fps(skel.fps if fps is None else fps, "fps")
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise StableMoError(f"{path}: unsupported animation format {suffix or '(none)'}; use .gif or .mp4")
    if suffix == ".mp4" and shutil.which("ffmpeg") is None:
        raise StableMoError(f"{path}: writing .mp4 needs ffmpeg on PATH (not found); write a .gif instead")
    if suffix == ".gif":
        _write_gif(_animation_frames(arr, skel, fps, title, targets), path, fps)
    else:
        _write_mp4(arr, skel, fps, title, path, targets)
    return path


def _check_targets(targets, joints: np.ndarray):
    if targets is None:
        return None
    positions, mask = (np.asarray(a) for a in targets)
    if positions.shape[1:] != joints.shape[1:] or mask.shape != positions.shape[:2]:
        raise StableMoError(f"targets: positions {positions.shape} and mask {mask.shape} do not fit joints {joints.shape}")
    return positions.astype(np.float64), mask.astype(bool)


def _frame_indices(num: int, count: int) -> list[int]:
    count = max(1, min(count, num))
    return sorted({int(round(i)) for i in np.linspace(0, num - 1, count)})


def save_png(fig, path: str | Path, dpi: int = DPI) -> None:
    """A matplotlib figure as a PNG, written atomically (the renders here and the scripts' plots)."""
    with atomic_open(path) as f:
        fig.savefig(f, format="png", dpi=dpi)


def render_strip(
    joints: np.ndarray,
    path: str | Path,
    skeleton: Skeleton | str = "humanml3d",
    num_frames: int = 8,
    title: str | None = None,
    targets: "tuple[np.ndarray, np.ndarray] | None" = None,
    frames: Sequence[int] | None = None,
) -> Path:
    """PNG with `num_frames` evenly spaced frames (or the given `frames`) side by side (same camera
    and scale); targets as in render_animation."""
    skel = get_skeleton(skeleton)
    arr = _check_joints(joints, skel)
    targets = _check_targets(targets, arr)
    path = Path(path)
    frames = _frame_indices(len(arr), num_frames) if frames is None else [int(f) for f in frames]
    view = _View(arr, skel)
    panel_w, head = 2.4, (0.55 if title else 0.25)
    fig = _figure(panel_w * len(frames), panel_w * view.aspect + head)
    top = 1.0 - head / fig.get_figheight()
    for i, t in enumerate(frames):
        ax = fig.add_axes((i / len(frames), 0.0, 1 / len(frames), top))
        _Panel(ax, arr, view, f"frame {t} ({t / skel.fps:.1f} s)", False, skel.fps, targets).show(t)
    if title:
        fig.suptitle(title, fontsize=10, y=0.99)
    save_png(fig, path)
    return path


def render_contact_sheet(
    motions: Sequence[np.ndarray],
    titles: Sequence[str] | None,
    path: str | Path,
    skeleton: Skeleton | str = "humanml3d",
    frames_per_row: int = 6,
) -> Path:
    """PNG grid: one row per motion (its title on the left), `frames_per_row` evenly spaced frames."""
    skel = get_skeleton(skeleton)
    if len(motions) == 0:
        raise StableMoError("motions: empty list, nothing to render")
    titles = list(titles) if titles is not None else [f"motion {i}" for i in range(len(motions))]
    if len(titles) != len(motions):
        raise StableMoError(f"titles: {len(titles)} titles for {len(motions)} motions")
    arrays = [_check_joints(m, skel, f"motions[{i}]") for i, m in enumerate(motions)]
    views = [_View(arr, skel) for arr in arrays]
    rows, cols = len(arrays), max(1, frames_per_row)
    label_w, cell_w = 1.6, 1.9
    fig = _figure(label_w + cell_w * cols, cell_w * max(v.aspect for v in views) * rows)
    x0 = label_w / fig.get_figwidth()
    for r, (arr, view, name) in enumerate(zip(arrays, views, titles)):
        y = 1 - (r + 1) / rows
        fig.text(0.01, y + 0.5 / rows, _wrap(name, 24), fontsize=8, va="center", ha="left")
        for c, t in enumerate(_frame_indices(len(arr), cols)):
            ax = fig.add_axes((x0 + c * (1 - x0) / cols, y, (1 - x0) / cols, 1 / rows))
            _Panel(ax, arr, view, None, False, skel.fps).show(t)
            ax.text(0.03, 0.03, f"{t / skel.fps:.1f} s", transform=ax.transAxes, fontsize=6, color="#666666")
    save_png(fig, Path(path))
    return Path(path)


def _wrap(text: str, width: int) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width)[:6]) or " "


# --------------------------------------------------------------------------- CLI


def _is_batch(shape: tuple[int, ...]) -> bool:
    skel = skeleton_for_shape(shape)
    if skel is None:
        return False
    return (len(shape) == 3 and shape[-1] == skel.feature_dim) or (len(shape) == 4 and shape[-1] == 3)


def load_motion(path: str | Path, skeleton: str | None = None, index: int | None = None) -> tuple[np.ndarray, Skeleton]:
    """Read a .npy of features (T, D) or joints (T, J, 3) — or a batch (N, T, D) / (N, T, J, 3) with
    `index` choosing the item; return joints (T, J, 3) and the skeleton."""
    path = Path(path)
    arr = load_npy(path)
    if _is_batch(arr.shape):
        if index is None:
            raise StableMoError(f"{path}: holds a batch of {arr.shape[0]} motions {arr.shape}; choose one with --index")
        if not -arr.shape[0] <= index < arr.shape[0]:
            raise StableMoError(f"--index: {index} out of range for {arr.shape[0]} motions in {path}")
        arr = np.asarray(arr[index])
    elif index is not None:
        raise StableMoError(f"--index: {path} holds a single motion {arr.shape}")
    if skeleton is not None:
        skel = get_skeleton(skeleton)
    else:
        skel = skeleton_for_shape(arr.shape) if arr.ndim in (2, 3) else None
        if skel is None:
            raise StableMoError(
                f"{path}: cannot tell the skeleton from shape {arr.shape}; expected features (T, 263|251) "
                "or joints (T, 22|21, 3)"
            )
    if not np.all(np.isfinite(arr)):
        raise StableMoError(f"{path}: contains NaN or Inf")
    if arr.ndim == 2 and arr.shape[1] == skel.feature_dim:
        if len(arr) < 1:
            raise StableMoError(f"{path}: no frames")
        return features_to_joints(arr.astype(np.float32), skel), skel
    if arr.ndim == 3 and arr.shape[1:] == (skel.num_joints, 3):
        return arr.astype(np.float64), skel
    raise StableMoError(
        f"{path}: shape {arr.shape} is neither features (T, {skel.feature_dim}) nor joints "
        f"(T, {skel.num_joints}, 3) of skeleton {skel.name}"
    )


