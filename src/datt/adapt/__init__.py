"""Adaptation: sources of the disturbance estimate ``d_hat``."""

from datt.adapt.base import Adaptation, Privileged, ZeroEstimate
from datt.adapt.l1 import L1Adaptation
from datt.adapt.rma import RmaAdaptation, RmaNet

__all__ = ["Adaptation", "Privileged", "ZeroEstimate", "L1Adaptation", "RmaAdaptation", "RmaNet"]
