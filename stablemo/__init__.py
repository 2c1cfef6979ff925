"""StableMo: text-to-motion generation by diffusion in motion space.

The public API, importable from here (each name loads its module on first use, so `import stablemo`
and `stablemo --help` stay instant):

    from stablemo import Pipeline, Request, JointControl
    pipe = Pipeline.from_bundle("stablemo/assets/demo_bundle")
    motion = pipe.generate(Request(["a person walks forward"], lengths=120, seed=0))
    motion.joints  # (B, T, 22, 3) metres, y up

Where things live (docs/architecture.md has the whole map):
    inference/  the pipeline, bundle kinds, bundles, inference config, hook factory
    training/   LightningModules (diffusion, consistency distillation, ControlNet), EMA, callbacks,
                checkpoint I/O, the Lightning CLI, export to bundles
    control/    in-painting and joint-control specs, control files, body parts, guidance, the ControlNet
    motion/     skeletons, features <-> joints, plausibility limits
    retarget/   a motion onto any humanoid rig (BVH, glTF/GLB, FBX through Blender)
    data/ text/ nets/ diffusion/ distill/ fast/ timeline/ skating/ eval/ outputs/ bvh/ gltf/ serve/ official/
    bench/      every benchmark;  cli/  every subcommand's argument parsing (one dispatch table)
"""

from __future__ import annotations

import importlib

_EXPORTS: dict[str, tuple[str, ...]] = {
    "stablemo.errors": ("StableMoError",),
    "stablemo.inference.pipeline": ("Generation", "Pipeline", "Request"),
    "stablemo.inference.bundle": ("load_bundle", "save_bundle"),
    "stablemo.inference.config": ("InferenceConfig",),
    "stablemo.inference.hooks": ("make_hooks",),
    "stablemo.control.spec": ("ControlTargets", "Inpaint", "JointControl"),
    "stablemo.control.turn": ("Turn",),
    "stablemo.control.files": ("load_control", "save_control"),
    "stablemo.motion": ("HUMANML3D", "KIT", "Skeleton", "features_to_joints", "get_skeleton", "joints_to_features"),
    "stablemo.timeline.spec": ("Segment", "parse_timeline", "read_timeline"),
    "stablemo.outputs.render": ("render_animation", "render_strip"),
    "stablemo.outputs.files": ("write_motion",),
    "stablemo.bvh": ("bvh_text", "export_motion", "read_bvh", "write_bvh"),
    "stablemo.gltf": ("glb_bytes", "motion_glb", "write_glb"),
    "stablemo.retarget": ("retarget_file",),  # not `retarget`: the name is the package's
}
# Training classes (DiffusionModule, MotionDataModule, ...) are not re-exported here: LightningCLI
# writes a class's shortest import path into configs and checkpoints, which must stay the module's.
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'stablemo' has no attribute {name!r}")
    value = getattr(importlib.import_module(_WHERE[name]), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_WHERE))
