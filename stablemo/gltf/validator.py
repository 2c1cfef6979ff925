"""Khronos' glTF validator (npm `gltf-validator`), installed into the virtual environment and run on
files we write (tests/test_gltf.py: 0 errors and 0 warnings on every one).

    stablemo vendor gltf-validator        # scripts/setup.sh runs it when npm is on PATH

The package goes under `<venv>/node/` (ignored by git with the venv; nothing third-party is
committed) at the pinned version, which npm checks against the registry's integrity hash. Node.js
runs it; `validate` answers None when node or the package is missing, so a test can skip.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

from stablemo.errors import StableMoError

VERSION = "2.0.0-dev.3.10"
PREFIX = Path(sys.prefix) / "node"
PACKAGE = PREFIX / "node_modules" / "gltf-validator"
# reads each file named on the command line, prints one JSON report per file
_RUNNER = """
const fs = require('fs');
const validator = require(process.argv[1]);
(async () => {
  const reports = [];
  for (const file of process.argv.slice(2)) {
    const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {maxIssues: 200});
    reports.push({file, errors: report.issues.numErrors, warnings: report.issues.numWarnings,
                  infos: report.issues.numInfos, messages: report.issues.messages, info: report.info});
  }
  process.stdout.write(JSON.stringify(reports));
})().catch((err) => { console.error(String(err)); process.exit(1); });
"""


def available() -> str | None:
    """None when node and the pinned validator are installed, else what is missing."""
    if shutil.which("node") is None:
        return "node is not installed (apt-get install npm brings it)"
    stamp = PACKAGE / "package.json"
    if not stamp.is_file() or json.loads(stamp.read_text()).get("version") != VERSION:
        return f"gltf-validator {VERSION} is not installed in {PREFIX}: run `stablemo vendor gltf-validator`"
    return None


def validate(paths: list[str | Path], timeout: float = 120.0) -> list[dict] | None:
    """One report per file ({file, errors, warnings, infos, messages: [{code, message, severity,
    pointer}], info}), or None when the validator is not available."""
    if available() is not None:
        return None
    run = subprocess.run(["node", "-e", _RUNNER, str(PACKAGE), *map(str, paths)], capture_output=True, text=True,
                         timeout=timeout, check=False)
    if run.returncode != 0:
        raise StableMoError(f"gltf-validator failed: {run.stderr.strip()[-500:]}")
    return json.loads(run.stdout)


def install(npm: str = "npm", timeout: float = 300.0) -> Path:
    exe = shutil.which(npm)
    if exe is None:
        raise StableMoError("npm: not found on PATH; install it (Debian/Ubuntu: `apt-get install npm`) and run "
                            "`stablemo vendor gltf-validator` again")
    PREFIX.mkdir(parents=True, exist_ok=True)
    try:
        subprocess.run([exe, "install", "--prefix", str(PREFIX), "--no-audit", "--no-fund", "--silent",
                        f"gltf-validator@{VERSION}"], check=True, timeout=timeout, capture_output=True, text=True)
    except subprocess.CalledProcessError as err:
        raise StableMoError(f"npm install gltf-validator@{VERSION} failed: {err.stderr.strip() or err}") from None
    except subprocess.TimeoutExpired:
        raise StableMoError(f"npm install gltf-validator@{VERSION}: no answer from the registry in {timeout:g} s") from None
    return PACKAGE

