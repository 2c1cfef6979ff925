"""Training: every LightningModule (diffusion, consistency distillation, ControlNet), EMA, callbacks, checkpoint I/O, the LightningCLI class, export to inference bundles."""
