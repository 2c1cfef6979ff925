"""Test-wide settings."""

import pytest
import torch


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread():
    # The tests run tiny models: with several threads torch spends its time synchronising, and on a
    # loaded 2-core machine a step is ~60x slower than with one thread. Results do not depend on it.
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def make_tiny_bundle(folder):
    """A tiny random diffusion bundle (HumanML3D features, lengths 8 to 40 frames) written to `folder`:
    fast enough for CLI tests of generate, edit and the output paths."""
    from stablemo.nets.model import MotionDiffusionModel
    from stablemo.inference.bundle import save_bundle

    config = {
        "model": {
            "denoiser": {"name": "unet", "input_dim": 263, "base_channels": 16, "channel_mults": [1, 2],
                         "time_dim": 32, "num_groups": 4, "num_heads": 2, "dropout": 0.0},
            "text": {"encoder": "minilm", "latent_dim": 32, "num_layers": 1, "num_heads": 2, "ff_dim": 64, "dropout": 0.0},
        },
        "schedule": {"num_train_timesteps": 1000},
        "prediction_type": "sample",
        "dataset": "humanml3d",
        "skeleton": "humanml3d",
        "fps": 20,
        "mean": [0.0] * 263,
        "std": [0.1] * 263,
        "min_length": 8,
        "max_length": 40,
        "kind": "diffusion",
    }
    torch.manual_seed(0)
    model = MotionDiffusionModel(**config["model"])
    for p in model.parameters():  # the output conv is zero-initialised; give the net a real output
        torch.nn.init.normal_(p, std=0.05)
    return save_bundle(folder, config, model.state_dict())
