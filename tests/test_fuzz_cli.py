"""Seeded fuzz of the cheap commands' numeric options (hypothesis is not a dependency).

Every value a user could type where a number is expected (0, -1, +-1e308, nan, inf, 1e-300, huge
integers, empty strings, words) must end in exit 0 or 2: on failure one line `stablemo <cmd>...
error: ...` (argparse's usage line may precede it), never a traceback, and nothing written outside
the run's own output folder. Each command runs in-process on tiny sizes (the demo bundle at 40
frames and 1 step, a 16-channel network for `nets summary`), so the whole sweep stays well under
a minute on two cores.
"""

from __future__ import annotations

import random
import sys
from pathlib import Path

import numpy as np
import pytest

from stablemo import cli

REPO = Path(__file__).resolve().parents[1]
DEMO_BUNDLE = REPO / "stablemo" / "assets" / "demo_bundle"
VALUES = ["0", "-1", "1", "3", "1.5", "1e308", "-1e308", "nan", "inf", "-inf", "1e-300", str(2**64),
          str(10**40), "-" + str(2**63), "", " ", "abc", "0x10", "1e3"]
RANDOM_PER_OPTION = 4  # seeded random values per option, beside the fixed ones (a fixed budget)
SEED = 20240601
TINY_NET = "name: unet\ninput_dim: 263\ntext_dim: 32\nbase_channels: 16\nchannel_mults: [1, 2]\ntime_dim: 32\n" \
           "num_groups: 4\nnum_heads: 2\n"


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    """A real (demo-generated) motion, its joints, and a tiny network config, in their own folder."""
    folder = tmp_path_factory.mktemp("inputs")
    assert cli.main(["generate", "a person walks", "--frames", "40", "--steps", "1", "--no-render",
                     "--out", str(folder)]) == 0
    features = folder / "a-person-walks.features.npy"
    np.save(folder / "short.features.npy", np.load(features)[:6])  # renders in a moment
    (folder / "tiny_net.yaml").write_text(TINY_NET)
    return {"features": features, "joints": folder / "a-person-walks.joints.npy",
            "short": folder / "short.features.npy", "net": folder / "tiny_net.yaml"}


def cases(inputs: dict[str, Path], out: Path) -> list[tuple[str, list[str], str]]:
    """(command, argv before the fuzzed option, option) for every numeric option of the cheap commands."""
    generate = ["generate", "a person walks", "--frames", "40", "--steps", "1", "--no-render", "--bundle",
                str(DEMO_BUNDLE), "--out", str(out / "gen")]
    # --json under a regular file: a valid value stops at that check instead of timing a benchmark
    bench = ["bench", "aits", "--bundle", str(DEMO_BUNDLE), "--random-weights", "--repeats", "1", "--steps", "1",
             "--skip-ddpm", "--skip-student", "--json", str(inputs["net"] / "x.json")]
    render = ["render", str(inputs["short"]), "--out", str(out / "r.gif")]
    bvh = ["bvh", str(inputs["features"]), "--out", str(out / "m.bvh")]
    control = ["control-file", str(inputs["joints"]), "--out", str(out / "c.npz")]
    footskate = ["footskate", str(inputs["features"]), "--out", str(out / "f.npy"), "--iters", "2"]
    nets = ["nets", "summary", "--config", str(inputs["net"]), "--length", "8"]
    table = [
        (generate, ["--frames", "--seconds", "--steps", "--cfg", "--seed"]),
        (bench, ["--frames", "--repeats", "--steps", "--cfg", "--ddpm-steps", "--threads", "--seed"]),
        (render, ["--fps", "--num-frames", "--index"]),
        (bvh, ["--fps", "--source-fps"]),
        (control, ["--density", "--frames"]),
        (footskate, ["--iters", "--fps", "--seed", "--threads"]),
        (nets, ["--length", "--text-length", "--input-dim", "--text-dim", "--depth", "--seed"]),
    ]
    return [(base[0], base, option) for base, options in table for option in options]


def random_value(rng: random.Random) -> str:
    """A number of any sign and magnitude as text (integer, decimal, exponent), or a stray string."""
    kind = rng.randrange(4)
    if kind == 0:  # tiny or huge: a valid mid-sized count (--steps 700) would make a slow run, not a test
        return str(rng.choice([-1, 1]) * rng.choice([rng.randrange(10), 10 ** rng.randrange(6, 25) + rng.randrange(999)]))
    if kind == 1:
        return f"{rng.uniform(-1, 1) * 10 ** rng.randrange(-5, 6):.6g}"
    if kind == 2:
        return f"{rng.choice(['', '-'])}1e{rng.randrange(-400, 400)}"
    return rng.choice(["1,2", "--", "١٢", "1_0", "+5", "5%", "0:3", "1e", "none"])


def snapshot(*folders: Path) -> set[Path]:
    return {p for folder in folders for p in folder.rglob("*")}


def test_numeric_options_never_end_in_a_traceback(inputs, tmp_path, monkeypatch, capsys):
    rng = random.Random(SEED)
    cwd, out = tmp_path / "cwd", tmp_path / "out"
    cwd.mkdir()
    out.mkdir()
    monkeypatch.chdir(cwd)
    before_inputs = snapshot(inputs["net"].parent)
    capsys.readouterr()
    failures = []
    for command, base, option in cases(inputs, out):
        for value in VALUES + [random_value(rng) for _ in range(RANDOM_PER_OPTION)]:
            argv = [*base, option, value]
            try:
                rc = cli.main(argv)
            except SystemExit as exit_:  # argparse's own refusal of a value its type cannot read
                rc = exit_.code
            except Exception as uncaught:  # noqa: BLE001 - what the console script prints as a traceback
                rc = f"{type(uncaught).__name__}: {uncaught}"
                print("Traceback (uncaught by stablemo.cli.main)", file=sys.stderr)
            err = capsys.readouterr().err
            errors = [line for line in err.splitlines() if line.startswith(f"stablemo {command}") and "error:" in line]
            problem = None
            if "Traceback" in err:
                problem = f"traceback ({rc})"
            elif rc not in (0, 2):
                problem = f"exit {rc}"
            elif rc == 2 and len(errors) != 1:
                problem = f"{len(errors)} error lines"
            elif rc == 0 and errors:
                problem = "an error line with exit 0"
            elif snapshot(cwd) or snapshot(inputs["net"].parent) != before_inputs:
                problem = "wrote outside --out"
            if problem:
                failures.append(f"{problem}: stablemo {' '.join(repr(a) if not a or ' ' in a else a for a in argv)}"
                                f"\n{err[-600:]}")
    assert not failures, "\n\n".join(failures)
