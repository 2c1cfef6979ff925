"""footskate: vGRF networks, contacts, and batched foot-skate cleanup on joint positions (torch only).

Joint positions in (metres, floor at 0), positions / contacts / forces out. StableMo calls this
package through `stablemo.skating.cleanup`; this package never imports stablemo.

The public names load lazily (PEP 562): `footskate.atomicio`, the project's one write helper, is
imported by every StableMo command and must not pull in torch with it. The cleanup itself is
`footskate.cleanup.cleanup` (the package's `cleanup` is that module).
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    # the function `cleanup` is footskate.cleanup.cleanup: the package attribute `cleanup` is its module
    "footskate.cleanup": ("CleanupConfig", "CleanupResult", "anchor_drift", "detect_contacts"),
    "footskate.contacts": ("contacts_from_forces", "contacts_from_heights"),
    "footskate.errors": ("FootskateError",),
    "footskate.skeletons": ("HUMANML3D", "KIT", "UP23", "Topology"),
    "footskate.vgrf": ("ATTRIBUTION", "VGRFNet", "load_underpressure", "load_vgrf", "save_vgrf"),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'footskate' has no attribute {name!r}")
    value = getattr(importlib.import_module(_WHERE[name]), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_WHERE))
