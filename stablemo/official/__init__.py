"""Published StableMoFusion checkpoints in StableMo (`stablemo import-official`, docs/official.md).

`layout` maps the official `T2MUnet` state dict onto `MotionDiffusionModel` with the official
variants of the text path and the UNet (`TextConditioner(variant="official")`,
`CondUNet1D(variant="official")`); `convert` writes the bundle.
"""

from stablemo.official.convert import import_official

__all__ = ["import_official"]
