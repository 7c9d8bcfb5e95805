"""Latency compensation for the off-board loop: the state the policy is shown is the vehicle's
estimate rolled forward over the loop's latency with the commands already on their way.

Off-board, the estimate a tick reads is old (the firmware sampled it, the log block crossed the
radio: ``up``, half the radio round trip) and the command it sends acts later still (the radio
again, the vehicle's own actuation delay: ``down``). ``latency_s``, the whole chain from the
estimate's measurement to the command's effect (what the calibration flight measures, or null:
the param round trip measured at connect plus ``policy_delay_s``), is ``up + down``. The policy
was trained with ``policy_delay_s`` of command delay (one 20 ms step): it expects its command to
act that long after the state it sees. :class:`StatePredictor` therefore integrates the estimate
from its measurement (``arrived - up``) to ``now + down - policy_delay_s``, each command sent
acting from ``down`` after it was sent.

The model is the controller's own (the training simulator's): mass-normalised collective thrust
along body z, gravity, the adaptation's disturbance estimate d̂, and thrust and body rates that
follow the command with the first-order lags ``k_thrust`` and ``k_rate`` per ``dt_s`` step.
Frames: world z up, quaternions (w, x, y, z) body to world, rates in the body frame.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass

import torch

from datt.configuration import NON_NEGATIVE, Range, check_ranges, ranged
from datt.sim.frames import quat_body_z, quat_exp_rotvec, quat_mul, quat_normalize


@dataclass
class PredictorParams:
    """``deploy.predictor``."""

    enabled: bool = False
    # the chain from the estimate's measurement to the command's effect (s); null = the radio round trip
    # measured at connect + policy_delay_s (a vehicle that actuates with the policy's trained delay)
    latency_s: float | None = ranged(None, Range(0.0, 0.5, optional=True))
    policy_delay_s: float = ranged(0.02, NON_NEGATIVE)  # the command delay the policy was trained with
    substep_s: float = ranged(0.005, Range(0.0, 0.02, low_open=True))  # integration step

    def validate(self) -> None:
        check_ranges(self, "deploy.predictor")


class StatePredictor:
    """Keeps the commands sent (with their send times) and rolls an estimate forward."""

    def __init__(
        self,
        params: PredictorParams,
        gravity_mps2: float,
        k_rate: float,
        dt_s: float,
        round_trip_s: float = math.inf,
        k_thrust: float = 1.0,
    ) -> None:
        self.p = params
        self.gravity_mps2 = float(gravity_mps2)
        self.k_rate, self.k_thrust, self.dt_s = float(k_rate), float(k_thrust), float(dt_s)
        self.round_trip_s = float(round_trip_s)  # measured at connect (inf: unknown)
        self.sent: collections.deque = collections.deque(maxlen=64)  # (t_s, [thrust, wx, wy, wz])

    @property
    def latency_s(self) -> float:
        if self.p.latency_s is not None:
            return float(self.p.latency_s)
        return self.round_trip_s + self.p.policy_delay_s

    @property
    def up_s(self) -> float:
        """How old an estimate is when it arrives: half the round trip (at most the whole chain)."""
        rtt = self.round_trip_s if math.isfinite(self.round_trip_s) else self.latency_s
        return min(rtt / 2, self.latency_s)

    @property
    def lead_s(self) -> float:
        """How far the predicted state is ahead of the tick that reads it: ``down −
        policy_delay_s`` (at least 0). The policy's reference window is read as far ahead."""
        return max(0.0, self.latency_s - self.up_s - self.p.policy_delay_s)

    def record(self, t_s: float, action) -> None:
        """A command sent at ``t_s`` (monotonic): thrust m/s², body rates rad/s."""
        self.sent.append((float(t_s), torch.as_tensor(action, dtype=torch.float64)[:4].clone()))

    def _command_at(self, t_s: float, down_s: float) -> torch.Tensor | None:
        """The command acting at ``t_s``: the last one sent before ``t_s - down_s``."""
        acting = None
        for sent_t, action in self.sent:
            if sent_t + down_s <= t_s:
                acting = action
            else:
                break
        return acting

    def predict(self, now_s: float, arrived_s: float, pos_m, vel_mps, quat, d_hat_mps2) -> tuple:
        """The estimate that arrived at ``arrived_s`` rolled forward to ``now_s + down -
        policy_delay_s``; returns (pos, vel, quat) as tuples (unchanged when disabled, the horizon
        is not positive or no command was sent yet)."""
        if not self.p.enabled or not self.sent or not math.isfinite(self.latency_s):
            return tuple(pos_m), tuple(vel_mps), tuple(quat)
        up = self.up_s
        down = self.latency_s - up
        t0 = arrived_s - up
        horizon_s = now_s + down - self.p.policy_delay_s - t0
        if horizon_s <= 0:
            return tuple(pos_m), tuple(vel_mps), tuple(quat)
        f64 = torch.float64
        pos, vel = torch.tensor(pos_m, dtype=f64), torch.tensor(vel_mps, dtype=f64)
        q = torch.tensor(quat, dtype=f64)
        d = torch.as_tensor(d_hat_mps2, dtype=f64)
        g = torch.tensor([0.0, 0.0, -self.gravity_mps2], dtype=f64)
        first = self._command_at(t0, down)
        rate = torch.zeros(3, dtype=f64) if first is None else first[1:].clone()
        thrust = self.gravity_mps2 if first is None else float(first[0])
        steps = max(1, int(math.ceil(horizon_s / self.p.substep_s)))
        h = horizon_s / steps
        alpha = 1.0 - (1.0 - self.k_rate) ** (h / self.dt_s)
        beta = 1.0 - (1.0 - self.k_thrust) ** (h / self.dt_s)
        for k in range(steps):
            command = self._command_at(t0 + k * h, down)
            if command is None:
                continue
            thrust = thrust + beta * (float(command[0]) - thrust)
            rate = rate + alpha * (command[1:] - rate)
            acc = thrust * quat_body_z(q) + g + d
            pos = pos + vel * h + 0.5 * acc * h * h
            vel = vel + acc * h
            q = quat_normalize(quat_mul(q, quat_exp_rotvec(rate * h)))
        return tuple(pos.tolist()), tuple(vel.tolist()), tuple(q.tolist())
