import pytest
import torch

from datt.config import compose, make_env


@pytest.fixture(autouse=True)
def _deterministic_threads():
    torch.set_num_threads(max(1, min(2, torch.get_num_threads())))
    yield


@pytest.fixture
def make_tracking_env():
    """Build an env from the Hydra config with overrides, e.g. ``make_tracking_env(["traj=star"], n=4)``."""

    def build(overrides=(), n=8, seed=0):
        return make_env(compose("sim", list(overrides)), num_envs=n, seed=seed)

    return build
