"""footskate: vGRF networks, contacts, and batched foot-skate cleanup on joint positions (torch only).

Joint positions in (metres, floor at 0), positions / contacts / forces out. StableMo calls this
package through `stablemo.footskate_guidance`; this package never imports stablemo.
"""

from footskate.cleanup import CleanupConfig, CleanupResult, anchor_drift, cleanup, detect_contacts
from footskate.contacts import contacts_from_forces, contacts_from_heights
from footskate.errors import FootskateError
from footskate.skeletons import HUMANML3D, KIT, UP23, Topology
from footskate.vgrf import ATTRIBUTION, VGRFNet, load_underpressure, load_vgrf, save_vgrf

__all__ = [
    "ATTRIBUTION", "CleanupConfig", "CleanupResult", "FootskateError", "HUMANML3D", "KIT", "Topology", "UP23",
    "VGRFNet", "anchor_drift", "cleanup", "contacts_from_forces", "contacts_from_heights", "detect_contacts",
    "load_underpressure", "load_vgrf", "save_vgrf",
]
