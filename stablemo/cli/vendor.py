"""`stablemo vendor three|gltf-validator`: fetch the pinned JavaScript the page and the glTF tests
use, from npm, at setup time (scripts/setup.sh runs both when npm is on PATH; nothing third-party
is committed). The work is the library's: stablemo.serve.vendor and stablemo.gltf.validator."""

from __future__ import annotations

import argparse


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="stablemo vendor", description="install pinned npm packages")
    parser.add_argument("package", choices=["three", "gltf-validator"],
                        help="three: three.js for `stablemo serve`'s page (into stablemo/serve/static/vendor/); "
                             "gltf-validator: Khronos' validator for the GLB tests (into <venv>/node/)")
    return parser


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    if args.package == "three":
        from stablemo.serve.vendor import THREE_VERSION, vendor

        print(f"three.js {THREE_VERSION} vendored in {vendor()}")
    else:
        from stablemo.gltf.validator import VERSION, install

        print(f"gltf-validator {VERSION} installed in {install()}")
    return 0
