"""footskate: vGRF networks, contacts, and batched foot-skate cleanup on joint positions (torch only).

Joint positions in (metres, floor at 0), positions / contacts / forces out. StableMo calls this
package through `stablemo.skating.cleanup`; this package never imports stablemo.

The public names load lazily (PEP 562): `footskate.atomicio`, the project's one write helper, is
imported by every StableMo command and must not pull in torch with it.
"""

from __future__ import annotations

import importlib
import sys
import types

_EXPORTS = {
    "footskate.cleanup": ("CleanupConfig", "CleanupResult", "anchor_drift", "cleanup", "detect_contacts"),
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


class _Package(types.ModuleType):
    def __setattr__(self, name: str, value) -> None:
        # Importing submodule footskate.cleanup binds the module here; the package's `cleanup` is
        # the function of that name (as with the former eager `from footskate.cleanup import cleanup`).
        if isinstance(value, types.ModuleType) and _WHERE.get(name) == value.__name__:
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
