import os

import pytest
import torch

from datt.configuration import compose
from datt.envs.factory import make_env

# Under pytest-xdist (the default: 4 workers on the machine's cores) each worker computes on one
# thread: more would oversubscribe the cores and slow the real-time flight tests' servers.
THREADS = 1 if os.environ.get("PYTEST_XDIST_WORKER") else max(1, min(2, torch.get_num_threads()))


@pytest.fixture(autouse=True)
def _deterministic_threads():
    torch.set_num_threads(THREADS)
    yield


@pytest.fixture
def make_tracking_env():
    """Build an env from the Hydra config with overrides, e.g. ``make_tracking_env(["traj=star"], n=4)``."""

    def build(overrides=(), n=8, seed=0):
        return make_env(compose("sim", list(overrides)), num_envs=n, seed=seed)

    return build


@pytest.fixture(scope="session")
def tiny_policy_checkpoint(tmp_path_factory):
    """A policy checkpoint from a two-iteration training run (shape-correct, barely trained)."""
    return train_tiny_policy(tmp_path_factory.mktemp("tiny_policy"))


@pytest.fixture(scope="session")
def tiny_authors_timing_checkpoint(tmp_path_factory):
    """The same, trained with the authors' observation timing and encoder."""
    run_dir = tmp_path_factory.mktemp("tiny_authors")
    return train_tiny_policy(run_dir, "env.obs.timing=authors", "policy.encoder=authors")


def train_tiny_policy(run_dir, *extra):
    from datt.train.loggers import CsvLogger
    from datt.train.ppo import Trainer

    cfg = compose(
        "train",
        [
            "logger=csv",
            "env.compile=false",
            "train.progress=false",
            "algo.num_envs=32",
            "algo.rollout_steps=8",
            "algo.minibatch_size=256",
            "algo.epochs=1",
            "train.total_frames=512",
            "curriculum.fixed_ref_frames=0",
            *extra,
        ],
    )
    trainer = Trainer(cfg, run_dir, CsvLogger(run_dir))
    trainer.train()
    return run_dir / "last.pt"
