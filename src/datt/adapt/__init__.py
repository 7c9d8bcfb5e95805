"""Adaptation: sources of the disturbance estimate ``d_hat``."""

from datt.adapt.base import Adaptation, Privileged, ZeroEstimate

__all__ = ["Adaptation", "Privileged", "ZeroEstimate"]
