"""TorchRL environments."""

from datt.envs.observations import STATE_DIM, build_observation
from datt.envs.tracking import TrackingEnv

__all__ = ["TrackingEnv", "build_observation", "STATE_DIM"]
