"""scripts/results/after_ship.sh: the steps it would run name scripts that exist, and its options answer
in one line."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "scripts" / "results" / "after_ship.sh"


def _run(*args):
    return subprocess.run(["bash", str(SCRIPT), *args], cwd=REPO, capture_output=True, text=True)


def _step_names() -> list[str]:
    """The steps in their order, as `--list` names them."""
    return [line.split()[0] for line in _run("--list").stdout.splitlines() if line.strip()]


def test_dry_run_commands_name_existing_scripts_and_run_nothing():
    done = _run("--dry-run")
    assert done.returncode == 0, done.stderr
    names = _step_names()
    assert len(names) == len(set(names)) >= 20
    for name in names:  # every step prints its header and at least one command
        assert f"# {name}: " in done.stdout
    scripts = set(re.findall(r"scripts/[\w/]+\.(?:py|sh)", done.stdout))
    assert scripts and all((REPO / s).is_file() for s in scripts), sorted(s for s in scripts if not (REPO / s).is_file())


def test_dry_run_from_a_step_starts_there():
    names = _step_names()
    done = _run("--dry-run", "--from", names[-2], "--skip", names[-1])
    assert done.returncode == 0, done.stderr
    headers = re.findall(r"^# (\w+): ", done.stdout, flags=re.MULTILINE)
    assert headers == [names[-2]]


def test_dry_run_to_a_step_stops_there():
    names = _step_names()
    for args, expected in ((["--to", names[1]], names[:2]), (["--from", names[2], "--to", names[4]], names[2:5]),
                           (["--from", names[3], "--to", names[3]], names[3:4])):
        done = _run("--dry-run", *args)
        assert done.returncode == 0, done.stderr
        assert re.findall(r"^# (\w+): ", done.stdout, flags=re.MULTILINE) == expected


def test_bad_options_get_one_line_and_exit_2():
    names = _step_names()
    for args, says in ((["--bogus"], "unknown option '--bogus'"), (["--from"], "--from needs a step name"),
                       (["--from", "nothing"], "--from: no step 'nothing'"), (["--to"], "--to needs a step name"),
                       (["--from", names[3], "--to", names[1]], f"--to {names[1]} comes before --from {names[3]}")):
        done = _run(*args)
        assert done.returncode == 2
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and says in lines[0], done.stderr
