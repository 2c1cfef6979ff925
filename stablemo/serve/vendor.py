"""Vendor the page's JavaScript library (three.js) from its npm package, at setup time.

    stablemo vendor three          # scripts/setup.sh runs it when npm is on PATH

`npm pack` fetches the pinned release tarball (npm checks it against the registry); we check it
again against the integrity pinned here, and copy the few files the page imports into
`stablemo/serve/static/vendor/three/` (gitignored: third-party code is never committed). At run
time the server reads them from disk, so the page needs no network.
"""

from __future__ import annotations

import base64
import hashlib
import shutil
import subprocess
import tarfile
import tempfile
from pathlib import Path

from stablemo.errors import StableMoError
from stablemo.io import atomic_dir, write_bytes

THREE_VERSION = "0.187.0"
# sha512 of three-0.187.0.tgz as the npm registry publishes it (`npm view three@0.187.0 dist.integrity`)
THREE_INTEGRITY = "sha512-Qiu7R+Cmh8CstZsY1uJOSWnVlfo7ZtNLV7mF8Jltk3LB3AtDu9cRZlcnRKkAk8Y4z6KKw35z7Y7Urd7jWY8etA=="
VENDOR_DIR = Path(__file__).resolve().parent / "static" / "vendor"
# tarball member -> path under VENDOR_DIR (the page's import map names these)
FILES = {
    "package/build/three.module.js": "three/three.module.js",
    "package/build/three.core.js": "three/three.core.js",
    "package/examples/jsm/controls/OrbitControls.js": "three/addons/controls/OrbitControls.js",
    # the page's body is our GLB, read by three.js's own glTF loader (and the two modules it imports)
    "package/examples/jsm/loaders/GLTFLoader.js": "three/addons/loaders/GLTFLoader.js",
    "package/examples/jsm/utils/BufferGeometryUtils.js": "three/addons/utils/BufferGeometryUtils.js",
    "package/examples/jsm/utils/SkeletonUtils.js": "three/addons/utils/SkeletonUtils.js",
    "package/LICENSE": "three/LICENSE",
}
STAMP = "three/VERSION"


def missing(vendor_dir: Path | None = None) -> str | None:
    """None when the vendored files are in place for the pinned version, else what to run."""
    vendor_dir = VENDOR_DIR if vendor_dir is None else vendor_dir
    stamp = vendor_dir / STAMP
    ok = stamp.is_file() and stamp.read_text().strip() == THREE_VERSION
    if ok and all((vendor_dir / dest).is_file() for dest in FILES.values()):
        return None
    return (f"the page's three.js {THREE_VERSION} is not vendored in {vendor_dir}: run `stablemo vendor three` "
            "(needs npm, which comes with Node.js: `apt-get install npm` on Debian/Ubuntu) or `bash scripts/setup.sh`")


def vendor(vendor_dir: Path | None = None, npm: str = "npm", timeout: float = 300.0) -> Path:
    vendor_dir = VENDOR_DIR if vendor_dir is None else vendor_dir
    exe = shutil.which(npm)
    if exe is None:
        raise StableMoError("npm: not found on PATH; install Node.js's npm (Debian/Ubuntu: `apt-get install npm`) "
                            "and run `stablemo vendor three` again")
    with tempfile.TemporaryDirectory(prefix="stablemo-vendor-") as tmp:
        try:
            subprocess.run([exe, "pack", f"three@{THREE_VERSION}", "--silent", "--pack-destination", tmp],
                           check=True, timeout=timeout, capture_output=True, text=True)
        except subprocess.CalledProcessError as err:
            raise StableMoError(f"npm pack three@{THREE_VERSION} failed: {err.stderr.strip() or err}") from None
        except subprocess.TimeoutExpired:
            raise StableMoError(f"npm pack three@{THREE_VERSION}: no answer from the npm registry in {timeout:g} s") from None
        tarball = Path(tmp) / f"three-{THREE_VERSION}.tgz"
        data = tarball.read_bytes()
        digest = "sha512-" + base64.b64encode(hashlib.sha512(data).digest()).decode("ascii")
        if digest != THREE_INTEGRITY:
            raise StableMoError(f"{tarball.name}: integrity {digest[:24]}... is not the pinned {THREE_INTEGRITY[:24]}...")
        contents = {}
        with tarfile.open(tarball, mode="r:gz") as tar:  # members read by exact name: nothing is extracted
            for member, dest in FILES.items():
                handle = tar.extractfile(member)
                if handle is None:
                    raise StableMoError(f"{tarball.name}: {member} missing from the package")
                contents[dest] = handle.read()
    # an older vendored copy (it has our stamp) is replaced whole; anything else there is left alone
    with atomic_dir(vendor_dir, replaceable=lambda old: (old / STAMP).is_file()) as out:
        for dest, blob in contents.items():
            (out / dest).parent.mkdir(parents=True, exist_ok=True)
            write_bytes(out / dest, blob)
        write_bytes(out / STAMP, (THREE_VERSION + "\n").encode())
    return vendor_dir

