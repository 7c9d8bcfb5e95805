"""Simulated Crazyflie: CRTP over UDP backed by :mod:`datt.sim`."""

from datt.deploy.sim.server import SimCrazyflie, SimCrazyflieParams

__all__ = ["SimCrazyflie", "SimCrazyflieParams"]
