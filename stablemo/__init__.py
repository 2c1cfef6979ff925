"""StableMo: text-to-motion diffusion in motion space."""

__version__ = "0.1.0"
