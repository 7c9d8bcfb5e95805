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

from datt.configuration import Range, check_ranges, ranged
from datt.sim.frames import body_z_floats, quat_turned_floats


@dataclass
class PredictorParams:
    """``deploy.predictor``."""

    # null: on when the policy flown was trained behind the predictor (its env.obs.predict_latency)
    # and the flight is off-board, off otherwise (a policy trained without it, a PID, onboard)
    enabled: bool | None = None
    # the chain from the estimate's measurement to the command's effect (s); null = the radio round trip
    # measured at connect + policy_delay_s (a vehicle that actuates with the policy's trained delay)
    latency_s: float | None = ranged(None, Range(0.0, 0.5, optional=True))
    policy_delay_s: float = ranged(0.02, Range(0.0, 0.5))  # the command delay the policy was trained with
    substep_s: float = ranged(0.005, Range(0.0, 0.02, low_open=True))  # integration step
    # the period at which the vehicle picks up a setpoint that has arrived (its control loop): 0 for
    # a real Crazyflie (its stabilizer reads setpoints at 1 kHz, finer than the integration step);
    # the simulated vehicle's physics step (deploy.server.dt_s) with deploy.server.log_before_step.
    # Above 0, a command acts from the vehicle's first loop tick after it arrived (the ticks placed
    # from the estimates' timestamps), not from the instant it arrived.
    vehicle_tick_s: float = ranged(0.0, Range(0.0, 0.1))
    # with vehicle_tick_s: the tick's compute before its send (s); TRACK's host tick is placed so that
    # its commands reach the vehicle half-way between two of its loop ticks (a few ms of compute or
    # radio jitter then never moves a command to another tick)
    compute_s: float = ranged(0.003, Range(0.0, 0.02))

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
        self.vehicle_tick_s = float(params.vehicle_tick_s)
        # the vehicle's clock against the host's: min over estimates of (arrival - vehicle time),
        # the least transit seen (the radio's fixed part; jitter only adds)
        self._transit_min_s = math.inf

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

    def lead_at(self, now_s: float) -> float:
        """:attr:`lead_s` for the tick at ``now_s``: with the vehicle's loop ticks known, the
        wait for the next one is part of it."""
        return max(0.0, self._acts_from(now_s, self.latency_s - self.up_s) - self.p.policy_delay_s - now_s)

    def observe(self, arrived_s: float, vehicle_s: float) -> None:
        """An estimate stamped ``vehicle_s`` by the vehicle's clock arrived at ``arrived_s`` (host,
        monotonic): places the vehicle's loop ticks on the host's clock."""
        self._transit_min_s = min(self._transit_min_s, float(arrived_s) - float(vehicle_s))

    def measured_at(self, vehicle_s: float) -> float:
        """The host time at which the vehicle measured an estimate stamped ``vehicle_s``: its
        least transit less the radio's one way (``up_s``)."""
        return float(vehicle_s) + self._transit_min_s - self.up_s

    @property
    def _ticks_placed(self) -> bool:
        """The vehicle has loop ticks to model and an estimate has placed them on the host's clock."""
        return self.vehicle_tick_s > 0 and math.isfinite(self._transit_min_s)

    def picked_up(self, arrives_s: float) -> float:
        """When a setpoint that reaches the vehicle at ``arrives_s`` (host time) is picked up: the
        vehicle's first loop tick at or after it (the ticks are where its estimates were measured:
        ``measured_at`` of whole multiples of ``vehicle_tick_s``); itself with no tick or no clock."""
        tick = self.vehicle_tick_s
        if not self._ticks_placed:
            return arrives_s
        anchor = self.measured_at(0.0)
        return anchor + math.ceil((arrives_s - anchor) / tick - 1e-6) * tick

    def send_slot(self, earliest_s: float) -> float:
        """The first host time at or after ``earliest_s`` to start a tick whose command (sent
        ``compute_s`` later, reaching the vehicle ``up_s`` after that) arrives half-way between two
        of the vehicle's loop ticks; ``earliest_s`` itself with no tick or no clock."""
        tick = self.vehicle_tick_s
        if not self._ticks_placed:
            return earliest_s
        slot = self.measured_at(0.0) + tick / 2 - self.up_s - self.p.compute_s
        return slot + math.ceil((earliest_s - slot) / tick) * tick

    def _acts_from(self, sent_s: float, down_s: float) -> float:
        """When a command sent at ``sent_s`` starts to act: it reaches the vehicle ``up_s`` (the
        radio's one way) later, waits for the vehicle's next loop tick, then the rest of ``down_s``
        (the vehicle's actuation)."""
        radio = min(self.up_s, down_s)
        return self.picked_up(sent_s + radio) + (down_s - radio)

    def record(self, t_s: float, action) -> None:
        """A command sent at ``t_s`` (monotonic): thrust m/s², body rates rad/s."""
        self.sent.append((float(t_s), torch.as_tensor(action, dtype=torch.float64)[:4].clone()))

    def _acting(self, down_s: float) -> list:
        """Each command sent, as (when it starts to act, its values as floats), in sending order
        (the predictor's integration reads it with :func:`_acting_at`)."""
        return [(self._acts_from(t, down_s), [float(x) for x in a.tolist()]) for t, a in self.sent]

    def predict(
        self, now_s: float, arrived_s: float, pos_m, vel_mps, quat, d_hat_mps2, vehicle_s: float | None = None
    ) -> tuple:
        """The estimate that arrived at ``arrived_s`` (stamped ``vehicle_s`` by the vehicle's
        clock, when known) rolled forward to when the command sent now acts, less
        ``policy_delay_s``; returns (pos, vel, quat) as tuples (unchanged when disabled, the
        horizon is not positive or no command was sent yet)."""
        if not self.p.enabled or not self.sent or not math.isfinite(self.latency_s):
            return tuple(pos_m), tuple(vel_mps), tuple(quat)
        up = self.up_s
        down = self.latency_s - up
        if vehicle_s is not None:
            self.observe(arrived_s, vehicle_s)
        t0 = arrived_s - up if vehicle_s is None else self.measured_at(vehicle_s)
        horizon_s = self._acts_from(now_s, down) - self.p.policy_delay_s - t0
        if horizon_s <= 0:
            return tuple(pos_m), tuple(vel_mps), tuple(quat)
        # plain floats, not tensors: the tick waits for this (tensor ops on 3-vectors cost 4-8 ms)
        acting = self._acting(down)
        pos, vel, q = [float(x) for x in pos_m], [float(x) for x in vel_mps], [float(x) for x in quat]
        d = [float(x) for x in torch.as_tensor(d_hat_mps2, dtype=torch.float64).tolist()]
        first = _acting_at(acting, t0)
        rate = [0.0, 0.0, 0.0] if first is None else first[1:4]
        thrust = self.gravity_mps2 if first is None else first[0]
        steps = max(1, int(math.ceil(horizon_s / self.p.substep_s)))
        h = horizon_s / steps
        alpha = 1.0 - (1.0 - self.k_rate) ** (h / self.dt_s)
        beta = 1.0 - (1.0 - self.k_thrust) ** (h / self.dt_s)
        for k in range(steps):
            command = _acting_at(acting, t0 + k * h)
            if command is not None:  # before the first recorded command acts: hover thrust, no rates
                thrust = thrust + beta * (command[0] - thrust)
                rate = [r + alpha * (c - r) for r, c in zip(rate, command[1:4])]
            z = body_z_floats(q)
            acc = [thrust * z[i] + d[i] for i in range(3)]
            acc[2] -= self.gravity_mps2
            pos = [p + v * h + 0.5 * a * h * h for p, v, a in zip(pos, vel, acc)]
            vel = [v + a * h for v, a in zip(vel, acc)]
            q = quat_turned_floats(q, [r * h for r in rate])
        return tuple(pos), tuple(vel), tuple(q)


def _acting_at(acting: list, t_s: float) -> list | None:
    """The command acting at ``t_s`` of ``acting`` ((acts from, command), in sending order)."""
    command = None
    for acts_s, action in acting:
        if acts_s <= t_s:
            command = action
        else:
            break
    return command
