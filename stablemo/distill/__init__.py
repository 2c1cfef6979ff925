"""Consistency distillation: 1-4-step students (LCM, PCM), their sampling, targets and optional discriminator; the training step is stablemo.training.distill_module."""
