"""Controllers behind one interface (DATT policy, and the baselines)."""

from datt.control.base import Controller, HoverController
from datt.control.datt import DattController

__all__ = ["Controller", "DattController", "HoverController"]
