"""Inference: Request -> Generation (the pipeline), bundle kinds, bundles and the packaged demo assets, the inference config, the hook factory."""
