"""Diffusion: the noise schedule, samplers, classifier-free guidance, in-painting and the sample-hook protocol."""
