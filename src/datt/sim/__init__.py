"""Batched quadrotor simulator: dynamics, disturbances, frame math."""

from datt.sim.disturbances import Brownian, ConstantForce, Disturbance, DragPlate, NoDisturbance, Wind
from datt.sim.quadrotor import Quadrotor, QuadrotorParams, QuadState

__all__ = [
    "Quadrotor",
    "QuadrotorParams",
    "QuadState",
    "Disturbance",
    "NoDisturbance",
    "ConstantForce",
    "Brownian",
    "Wind",
    "DragPlate",
]
