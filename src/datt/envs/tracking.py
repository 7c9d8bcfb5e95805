"""TorchRL environment: N quadrotors tracking references, in one batched tensor.

Per step (dt = ``dt_s``): clip the action ``[thrust_mps2, wx, wy, wz]`` to its bounds, integrate
the sim with the disturbance d, advance the reference index, update d and d_hat, then build the
observation and reward from the *new* state and the reference at the *new* time
(``obs.timing = project``), or from the state *before* the step with the reference at the new
time (``obs.timing = authors``, the authors' env; see :class:`~datt.envs.params.ObsParams`).

Episodes: drones start at rest, level, uniformly within ``init_pos_range_m`` of the origin,
with a fresh reference (and disturbance) each; an episode is truncated after
``episode_steps`` steps and terminated when the drone leaves ``safety_box_m`` (half-extents
about the origin), exceeds ``max_tracking_error_m`` (if set) or its state is not finite.
Finished drones are reset individually (TorchRL ``_reset`` mask); the others keep flying.

With ``obs.action_history = k > 0`` the env keeps the last k commands it applied (scaled to
[-1, 1], ``cmd_history [N, k, 4]``, hover after a reset) and appends them to ``state``.
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from datt.adapt.base import Adaptation, Privileged
from datt.compile import compile_or_eager
from datt.configuration import check_horizon
from datt.envs.observations import critic_reference, observe_and_cost, state_width
from datt.envs.params import EnvParams
from datt.envs.prediction import roll_forward
from datt.errors import ConfigError
from datt.refs.base import RefFamily
from datt.sim.disturbances import Disturbance
from datt.sim.frames import quat_exp_rotvec, quat_mul, quat_normalize
from datt.sim.quadrotor import Quadrotor, resolve_dtype


def action_bounds(params: EnvParams, **kw) -> tuple[torch.Tensor, torch.Tensor]:
    """``(low, high)`` of the action ``[thrust_mps2, wx, wy, wz]``, each ``[4]``."""
    g = params.quad.gravity_mps2
    lo_t, hi_t = params.thrust_offset_bounds_mps2
    rates = torch.tensor(params.rate_bounds_radps, **kw)
    return torch.cat((torch.tensor([g + lo_t], **kw), -rates)), torch.cat((torch.tensor([g + hi_t], **kw), rates))


def action_center_half(low: torch.Tensor, high: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Midpoint and half-range of the bounds: ``action = center + half * u`` for ``u`` in [-1, 1]."""
    return (high + low) / 2, (high - low) / 2


class TrackingEnv(EnvBase):
    """Batched trajectory-tracking env (``batch_size = [num_envs]``).

    Observation keys: ``state [N, 13 + 4k]`` (k = ``obs.action_history``), ``ref [N, horizon, 3]``,
    ``d_hat [N, 3]``, with ``obs.critic_ref_points`` = K > 0 also ``critic_ref [N, K, 3]`` (see
    :mod:`datt.envs.observations`) and ``tracking_error_m [N, 1]`` (‖p − p_d(t)‖, true
    position; for logging and metrics). Action ``[N, 4]``: thrust (m/s², mass-normalised,
    bounds ``g + thrust_offset_bounds_mps2``) and body rates (rad/s, ± ``rate_bounds_radps``).
    Reward ``[N, 1]`` per :class:`datt.envs.params.RewardParams`.

    Controllers read the env through :meth:`control_input` (measured state, reference window and
    the reference further ahead, commands in flight, command history, d̂, step index) and
    :meth:`observe` (the policy observation); nothing outside ``envs/`` reads its private state.

    ``adaptation`` defaults to :class:`~datt.adapt.Privileged` (true d as ``d_hat``).
    """

    batch_locked = True

    def __init__(
        self,
        num_envs: int,
        traj: RefFamily,
        disturbance: Disturbance | None = None,
        adaptation: Adaptation | None = None,
        horizon: int = 10,
        params: EnvParams | None = None,
        seed: int | None = 0,
        device: str | torch.device | None = None,
    ) -> None:
        params = params or EnvParams()
        params.validate()
        check_horizon(horizon)
        if num_envs < 1:
            raise ConfigError(f"num_envs: must be >= 1, got {num_envs}")
        device = torch.device(device or params.device)
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self.params = params
        self.n = num_envs
        self.horizon = horizon
        self.dtype = resolve_dtype(params.dtype)
        self.dt_s = params.dt_s
        self.traj = traj
        self.disturbance = disturbance if disturbance is not None else Disturbance()
        self.adaptation = adaptation if adaptation is not None else Privileged()
        self.generator = torch.Generator(device=device)
        self.generator.manual_seed(0 if seed is None else int(seed))
        self._start_generator: torch.Generator | None = None  # see seed_starts

        kw = {"device": device, "dtype": self.dtype}
        self.sim = Quadrotor(num_envs, params.quad, dt_s=params.dt_s, device=device, dtype=self.dtype)
        g = params.quad.gravity_mps2
        self.disturbance.bind(num_envs, params.dt_s, self.generator, device, self.dtype)
        self.adaptation.bind(num_envs, params.dt_s, g, device, self.dtype)

        self._init_reference_buffers(params, horizon, num_envs, device)
        # Per-drone truncation step: episode_steps, except after stagger_episodes().
        self.episode_len = torch.full((num_envs,), params.episode_steps, dtype=torch.long, device=device)
        self._stagger_pending = False
        self._observe_kernel = observe_and_cost

        self.action_low, self.action_high = action_bounds(params, **kw)
        # what the vehicle takes: the action bounds, thrust also under the actuator's ceiling (on a
        # vehicle the thrust map clips at max_command); simulator, history and adaptation see it
        self.command_high = self.action_high.clone()
        self.command_high[0] = min(float(self.action_high[0]), params.quad.max_thrust_mps2)
        self.action_center, self.action_half = action_center_half(self.action_low, self.action_high)
        self.state_dim = state_width(params.obs)
        self.cmd_history = torch.zeros(num_envs, params.obs.action_history, 4, **kw)
        self.prev_cmd = torch.zeros(num_envs, 4, **kw)  # the last command applied (reward.rate_change)
        self.box_m = torch.tensor(params.safety_box_m, **kw)
        self._make_specs()
        self._all_idx = torch.arange(num_envs, device=device)
        self._ref_lead_steps = 0.0  # deployment behind a state predictor: set_reference_lead
        # obs.predict_latency_error_steps: the delay each drone is predicted over (None: its true one)
        self.assumed_delay = None
        if params.obs.predict_latency and params.obs.predict_latency_error_steps:
            self.assumed_delay = torch.ones(num_envs, dtype=torch.long, device=device)
        self._reset_drones(self._all_idx)

    def _init_reference_buffers(self, params: EnvParams, horizon: int, num_envs: int, device) -> None:
        """The reference table (episode + the furthest point read ahead, float64 time grid), the
        ring buffer of the policy's window and the critic's offsets, all in env steps."""
        spacing = round(params.ref_spacing_s / params.dt_s)
        self.ref_offsets = torch.arange(horizon, device=device) * spacing  # [H] steps ahead
        self.window = int(self.ref_offsets[-1]) + 1
        # the critic's points (obs.critic_ref_points = K): t + k Δc, k = 1..K, read from the table
        obs = params.obs
        critic_spacing = round(obs.critic_ref_spacing_s / params.dt_s)
        self.critic_offsets = torch.arange(1, obs.critic_ref_points + 1, device=device) * critic_spacing
        reach = int(self.critic_offsets[-1]) + 1 if obs.critic_ref_points else 0
        self.table_len = params.episode_steps + max(self.window, reach)
        # float64 grid: float32 times drift by ~1e-6 s at 10 s; the table is cast to `dtype`.
        self.t_grid_s = torch.arange(self.table_len, device=device, dtype=torch.float64) * params.dt_s
        self.ref_table = torch.zeros(num_envs, self.table_len, 3, device=device, dtype=self.dtype)
        # Ring buffer of the next `window` reference points, slot-major [W, N, 3] so that
        # reading the H points is a contiguous copy. Invariant, for every drone n:
        #   ref_window[(head + k) % W, n] == ref_table[n, step_idx[n] + k],  k = 0..W-1.
        self.ref_window = torch.zeros(self.window, num_envs, 3, device=device, dtype=self.dtype)
        self._head = 0
        self._row_base = torch.arange(num_envs, device=device) * self.table_len
        self.step_idx = torch.zeros(num_envs, dtype=torch.long, device=device)

    # -- specs -----------------------------------------------------------------------------
    def _make_specs(self) -> None:
        n, h, dev, dt = self.n, self.horizon, self.device, self.dtype
        self.observation_spec = Composite(
            state=Unbounded(shape=(n, self.state_dim), device=dev, dtype=dt),
            ref=Unbounded(shape=(n, h, 3), device=dev, dtype=dt),
            d_hat=Unbounded(shape=(n, 3), device=dev, dtype=dt),
            tracking_error_m=Unbounded(shape=(n, 1), device=dev, dtype=dt),
            shape=(n,),
            device=dev,
        )
        if len(self.critic_offsets):
            self.observation_spec["critic_ref"] = Unbounded(
                shape=(n, len(self.critic_offsets), 3), device=dev, dtype=dt
            )
        self.action_spec = Bounded(
            low=self.action_low.expand(n, 4), high=self.action_high.expand(n, 4), shape=(n, 4), device=dev, dtype=dt
        )
        self.reward_spec = Unbounded(shape=(n, 1), device=dev, dtype=dt)
        self.done_spec = Composite(
            done=Categorical(2, shape=(n, 1), dtype=torch.bool, device=dev),
            terminated=Categorical(2, shape=(n, 1), dtype=torch.bool, device=dev),
            truncated=Categorical(2, shape=(n, 1), dtype=torch.bool, device=dev),
            shape=(n,),
            device=dev,
        )

    # -- core ------------------------------------------------------------------------------
    def _set_seed(self, seed: int | None) -> None:
        self.generator.manual_seed(0 if seed is None else int(seed))

    def _reset_drones(self, idx: torch.Tensor) -> None:
        k = len(idx)
        r = self.params.init_pos_range_m
        gen = self._start_generator or self.generator
        u = torch.rand(k, 3, generator=gen, device=self.device, dtype=self.dtype)
        self.sim.reset(idx, (2.0 * u - 1.0) * r)
        self.sim.randomise(idx, self.generator)
        self._draw_assumed_delay(idx)
        self.step_idx[idx] = 0
        self.episode_len[idx] = self.params.episode_steps
        table = self.traj.sample(k, self.t_grid_s, self.generator).to(self.dtype)
        self.ref_table[idx] = table
        slots = (self._head + torch.arange(self.window, device=self.device)) % self.window
        self.ref_window[slots.unsqueeze(1), idx.unsqueeze(0)] = table[:, : self.window].transpose(0, 1)
        self.disturbance.reset(idx, self.sim.state)
        self.adaptation.reset(idx, self.disturbance.current_mps2, self.sim.state)
        if self.cmd_history.shape[1]:
            self.cmd_history[idx] = self.scaled_command(self.hover_action[idx]).unsqueeze(1)
        self.prev_cmd[idx] = self.hover_action[idx]

    def seed_starts(self, seed: int) -> None:
        """Draw the start positions of later resets from their own generator seeded at ``seed``
        (evaluation: every controller and disturbance of a seed starts from the same points,
        whatever else the env's generator has drawn)."""
        self._start_generator = torch.Generator(device=self.device).manual_seed(int(seed))

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        mask = None if tensordict is None else tensordict.get("_reset", None)
        if mask is None:
            idx = self._all_idx
        else:
            idx = mask.reshape(self.n).nonzero().squeeze(-1)
        if len(idx):
            self._reset_drones(idx)
        if len(idx) == self.n and self._stagger_pending:
            high = self.params.episode_steps + 1
            self.episode_len = torch.randint(1, high, (self.n,), generator=self.generator, device=self.device)
            self._stagger_pending = False
        out = self._observe(None if len(idx) == self.n else idx)[0]
        false = torch.zeros(self.n, 1, dtype=torch.bool, device=self.device)
        out.update({"done": false, "terminated": false.clone(), "truncated": false.clone()})
        return out

    def replace_reference(self, table: torch.Tensor) -> None:
        """Fly ``table`` (``[N, table_len, 3]``, world, m, at ``dt_s``) from now on: every drone's
        reference table replaced and its window refilled from its current step (deployment slows a
        reference in time this way, :mod:`datt.deploy.feasibility`)."""
        if tuple(table.shape) != tuple(self.ref_table.shape):
            raise ValueError(f"replace_reference: table {tuple(table.shape)}, need {tuple(self.ref_table.shape)}")
        self.ref_table.copy_(table)
        k = torch.arange(self.window, device=self.device)
        rows = (self.step_idx.unsqueeze(0) + k.unsqueeze(1)).clamp_max(self.table_len - 1)  # [W, N]
        slots = (self._head + k) % self.window
        self.ref_window[slots] = self.ref_table.view(-1, 3)[self._row_base.unsqueeze(0) + rows]

    def _ref_future(self) -> torch.Tensor:
        """The H reference points at t + iΔ for every drone, ``[H, N, 3]`` (world)."""
        slots = (self._head + self.ref_offsets) % self.window
        return self.ref_window.index_select(0, slots)

    def _advance_refs(self) -> None:
        """Move every drone one step along its reference (ring buffer shift + one new row)."""
        self.step_idx += 1
        last = (self.step_idx + (self.window - 1)).clamp_max(self.table_len - 1)
        new_row = self.ref_table.view(-1, 3).index_select(0, self._row_base + last)
        self.ref_window[self._head] = new_row  # the slot of the old "now" becomes the far end
        self._head = (self._head + 1) % self.window

    # -- public inputs of controllers ------------------------------------------------------------
    def control_input(self, ahead_steps: int = 0) -> TensorDict:
        """Everything a controller may read this step, as one TensorDict (``batch_size [N]``):

        * ``pos_m``, ``vel_mps [N, 3]`` (world), ``quat [N, 4]`` (w, x, y, z, body-to-world),
          ``rate_radps [N, 3]`` (body) and ``thrust_mps2 [N]`` (actuator outputs after the delay):
          the simulator's state (the measured state on hardware, see ``set_state``);
        * ``ref_window_m [N, H, 3]``: the H feedforward points p_d(t + iΔ), i = 0..H−1,
          Δ = ``ref_spacing_s`` (world; ``[:, 0]`` is the reference now);
        * ``ref_ahead_m [N, ahead_steps, 3]``: p_d(t + k dt), k = 1..``ahead_steps`` (world; held
          at the last point past the end of the reference table);
        * ``cmd_in_flight [N, L, 4]``: commands sent but not yet applied (L = ``latency_steps``),
          oldest first; ``cmd_history [N, k, 4]``: the last k commands scaled to [-1, 1]
          (``obs.action_history``);
        * ``d_hat [N, 3]``: the adaptation's disturbance estimate (world, m/s²);
        * ``step [N]``: steps since each drone's episode started.

        Tensors are views of the env's buffers where possible: read them, do not write them.
        """
        s = self.sim.state
        values = {
            "pos_m": s.pos_m,
            "vel_mps": s.vel_mps,
            "quat": s.quat,
            "rate_radps": s.rate_radps,
            "thrust_mps2": s.thrust_mps2,
            "ref_window_m": self._ref_future().transpose(0, 1),
            "ref_ahead_m": self._ref_ahead(ahead_steps),
            "cmd_in_flight": self.sim.latency.in_flight().transpose(0, 1),
            "cmd_history": self.cmd_history,
            "d_hat": self.adaptation.d_hat,
            "step": self.step_idx,
        }
        return TensorDict._new_unsafe(values, batch_size=self.batch_size, device=self.device)

    def observe(self) -> TensorDict:
        """The policy observation of every drone now (``state``, ``ref``, ``d_hat``,
        ``tracking_error_m``), as :meth:`step` returns it."""
        return self._observe()[0]

    def reference_now_m(self) -> torch.Tensor:
        """p_d(t) of every drone, ``[N, 3]`` (world)."""
        return self.ref_window[self._head]

    def advance_reference(self) -> None:
        """Move every drone one step along its reference without stepping the simulator (a real
        vehicle is the plant: deployment advances the reference each control tick)."""
        self._advance_refs()

    def set_state(self, pos_m, vel_mps, quat) -> None:
        """Overwrite the state the controllers read with a measurement ``[N, 3]``, ``[N, 3]``,
        ``[N, 4]`` (deployment: the vehicle's estimate each tick)."""
        s = self.sim.state
        s.pos_m.copy_(torch.as_tensor(pos_m, dtype=s.pos_m.dtype).reshape(s.pos_m.shape))
        s.vel_mps.copy_(torch.as_tensor(vel_mps, dtype=s.vel_mps.dtype).reshape(s.vel_mps.shape))
        s.quat.copy_(torch.as_tensor(quat, dtype=s.quat.dtype).reshape(s.quat.shape))

    def _ref_ahead(self, steps: int) -> torch.Tensor:
        """p_d(t + k dt), k = 1..steps: ``[N, steps, 3]`` (world), from the reference table."""
        if steps <= 0:
            return self.ref_table[:, :0]
        idx = self.step_idx.unsqueeze(1) + torch.arange(1, steps + 1, device=self.device)
        idx = idx.clamp_max(self.table_len - 1)
        return torch.gather(self.ref_table, 1, idx.unsqueeze(-1).expand(-1, -1, 3))

    def _observe(
        self, idx: torch.Tensor | None = None, read_state: tuple | None = None
    ) -> tuple[TensorDict, torch.Tensor, torch.Tensor]:
        """Observation, tracking error and cost for all drones, or only for rows ``idx``.

        With ``idx`` (partial reset) the other rows are left at zero: TorchRL keeps the previous
        observation of drones that were not reset, so computing them would be wasted work.
        ``read_state``: ``(pos, vel, quat)`` the observation and cost read instead of the simulator's
        state (``obs.timing = authors``: the state before the step); the tracking error always
        reads the simulator's.
        """
        s = self.sim.state
        pos, vel, quat = (s.pos_m, s.vel_mps, s.quat) if read_state is None else read_state
        future = self._ref_future()
        kernel = self._observe_kernel
        if idx is not None:
            pos, vel, quat, future = pos[idx], vel[idx], quat[idx], future[:, idx]
            kernel = observe_and_cost  # eager: subset sizes vary, avoid recompiles
        measured, seen = self._policy_state(self._measure(pos, vel, quat), idx)
        state, ref, err_m, cost = kernel(*measured, pos, vel, quat, future, self.params.obs, self.params.reward, seen)
        if read_state is not None:  # the metric: the simulator's state against the same-time reference
            err_m = torch.linalg.vector_norm(s.pos_m - future[0], dim=-1, keepdim=True)
        if self.cmd_history.shape[1]:
            hist = self.cmd_history if idx is None else self.cmd_history[idx]
            state = torch.cat((state, hist.flatten(1)), dim=-1)
        values = {"state": state, "ref": ref, "d_hat": self.adaptation.d_hat.clone(), "tracking_error_m": err_m}
        if len(self.critic_offsets):
            values["critic_ref"] = self._critic_ref(idx)
        if idx is not None:
            values["d_hat"] = values["d_hat"][idx]
            full = {}
            for key, val in values.items():
                full[key] = val.new_zeros((self.n, *val.shape[1:]))
                full[key][idx] = val
            values = full
        # values are built here with the right shapes and device: skip TensorDict's checks
        td = TensorDict._new_unsafe(values, batch_size=self.batch_size, device=self.device)
        return td, err_m, cost

    def policy_view(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """What the policy's observation is built from, without the observation noise:
        ``(pos [N, 3], vel [N, 3], quat [N, 4], window [H, N, 3])``, the simulator's state (the
        measurement on hardware) and the reference window, both as ``obs.predict_latency`` or
        :meth:`set_reference_lead` move them (controllers that build the observation themselves
        read this, as :meth:`observe` does)."""
        s = self.sim.state
        (pos, vel, quat), seen = self._policy_state((s.pos_m, s.vel_mps, s.quat), None)
        return pos, vel, quat, self._ref_future() if seen is None else seen

    def _policy_state(self, measured: tuple, idx: torch.Tensor | None) -> tuple[tuple, torch.Tensor | None]:
        """The measured ``(pos, vel, quat)`` of all drones (or rows ``idx``) and the reference
        window ``[H, N, 3]`` the observation reads: rolled forward and ahead under
        ``obs.predict_latency``, the window ahead by the deployment's lead, else the state as
        measured and None (the window now)."""
        if self.params.obs.predict_latency:
            return self._predict(measured, idx)
        if self._ref_lead_steps:
            rows = self._all_idx if idx is None else idx
            whole = int(self._ref_lead_steps)
            frac = self._ref_lead_steps - whole
            window = self._window_ahead(rows, torch.full_like(rows, whole))
            if frac:  # between two steps: linear interpolation (exact on the table's straight segments)
                window = torch.lerp(window, self._window_ahead(rows, torch.full_like(rows, whole + 1)), frac)
            return measured, window
        return measured, None

    def _draw_assumed_delay(self, idx: torch.Tensor) -> None:
        """``obs.predict_latency_error_steps`` = e > 0: the delay drones ``idx`` are predicted
        over this episode, their true one plus a uniform integer in −e..e, kept within
        1..``max_latency_steps`` (a deployed predictor's latency is measured, not known)."""
        err = self.params.obs.predict_latency_error_steps
        if not (self.params.obs.predict_latency and err):
            return
        latency = self.sim.latency
        off = torch.randint(-err, err + 1, (len(idx),), generator=self.generator, device=self.device)
        self.assumed_delay[idx] = (latency.delays()[idx] + off).clamp(1, max(latency.max_steps, 1))

    def _predict(self, measured: tuple, idx: torch.Tensor | None) -> tuple[tuple, torch.Tensor]:
        """``obs.predict_latency``: the measured ``(pos, vel, quat)`` of all drones (or rows
        ``idx``) rolled over each drone's commands in flight beyond one step
        (:func:`datt.envs.prediction.roll_forward`), and the reference window ``[H, N, 3]`` read
        as many steps ahead."""
        rows = self._all_idx if idx is None else idx
        commands, active, acting = self.sim.latency.pending(self.assumed_delay)
        commands, active = commands[:, rows], active[:, rows]
        predicted = roll_forward(
            *measured,
            acting[rows],
            commands,
            active,
            self.adaptation.d_hat[rows],
            self.sim.gravity,
            self.sim.params,
            self.dt_s,
        )
        return predicted, self._window_ahead(rows, active.sum(0))

    def _window_ahead(self, rows: torch.Tensor, lead_steps: torch.Tensor) -> torch.Tensor:
        """The policy's reference window of drones ``rows [k]`` read ``lead_steps [k]`` steps
        ahead of now, ``[H, k, 3]`` (world; held at the table's last point)."""
        return self._table_points(rows, lead_steps.unsqueeze(1) + self.ref_offsets).transpose(0, 1)

    def _table_points(self, rows: torch.Tensor, ahead: torch.Tensor) -> torch.Tensor:
        """Reference points ``[k, K, 3]`` (world) of drones ``rows [k]`` at ``ahead [k, K]`` (or
        ``[K]``) steps from now, held at the table's last point."""
        steps = (self.step_idx[rows].unsqueeze(1) + ahead).clamp_max(self.table_len - 1)
        flat = (self._row_base[rows].unsqueeze(1) + steps).reshape(-1)
        return self.ref_table.view(-1, 3).index_select(0, flat).view(len(rows), -1, 3)

    def set_reference_lead(self, steps: float) -> None:
        """Deployment behind a state predictor: the observation's reference window is read
        ``steps`` steps ahead of now (the time of the predicted state; a fraction interpolates
        between two steps; 0: now). Training reads its own lead from ``obs.predict_latency``."""
        if not steps >= 0 or not math.isfinite(steps):
            raise ValueError(f"reference lead: must be a finite number >= 0 steps, got {steps}")
        self._ref_lead_steps = float(steps)

    def _critic_ref(self, idx: torch.Tensor | None = None) -> torch.Tensor:
        """``critic_ref [N, K, 3]`` (or its rows ``idx``) from the true state: the critic is
        trained only in simulation, so it may read what the sensors do not give the policy."""
        s = self.sim.state
        rows = self._all_idx if idx is None else idx
        points = self._table_points(rows, self.critic_offsets)
        return critic_reference(s.pos_m[rows], s.quat[rows], points, self.params.obs.body_frame)

    def _measure(self, pos: torch.Tensor, vel: torch.Tensor, quat: torch.Tensor):
        """The state the policy observes: ``(pos, vel, quat)`` with the observation noise of
        ``obs`` (the true tensors themselves when a noise is off)."""
        obs = self.params.obs

        def noise(like: torch.Tensor, std: float) -> torch.Tensor:
            return std * torch.randn(like.shape, generator=self.generator, device=self.device, dtype=self.dtype)

        if obs.pos_noise_std_m > 0:
            pos = pos + noise(pos, obs.pos_noise_std_m)
        if obs.vel_noise_std_mps > 0:
            vel = vel + noise(vel, obs.vel_noise_std_mps)
        if obs.att_noise_std_rad > 0:
            quat = quat_normalize(quat_mul(quat, quat_exp_rotvec(noise(vel, obs.att_noise_std_rad))))
        return pos, vel, quat

    def advance_plant(self, action: torch.Tensor):
        """The plant's half of a step: clamp the command, integrate, move the references on and
        update the disturbance. Returns ``(state, cmd, d)`` for the controller's half
        (adaptation update, observation), which :meth:`_step` and the latency timer run next."""
        cmd = torch.clamp(action, self.action_low, self.command_high)
        ceiling = self.sim.command_ceiling_mps2
        if ceiling is not None:  # a trimmed map's ceiling differs per drone (env.quad.thrust_map_trimmed)
            cmd[:, 0] = torch.minimum(cmd[:, 0], ceiling)  # cmd is clamp's own copy
        self.record_command(cmd)
        s = self.sim.step(cmd, self.disturbance.current_mps2)
        self._advance_refs()
        return s, cmd, self.disturbance.update(s)

    def scaled_command(self, cmd: torch.Tensor) -> torch.Tensor:
        """Command ``[..., 4]`` scaled by the action bounds to [-1, 1] (the history's units)."""
        return (cmd - self.action_center) / self.action_half

    def record_command(self, cmd: torch.Tensor) -> None:
        """Append a (clamped) command ``[N, 4]`` to ``cmd_history`` (no-op without history).
        Deployment calls it for the commands it sends, as the env step does."""
        if self.cmd_history.shape[1]:
            self.cmd_history = torch.cat((self.cmd_history[:, 1:], self.scaled_command(cmd).unsqueeze(1)), dim=1)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        before = None
        if self.params.obs.timing == "authors":  # observation and reward read the state before the step
            st = self.sim.state
            before = (st.pos_m.clone(), st.vel_mps.clone(), st.quat.clone())
        s, cmd, d = self.advance_plant(tensordict.get("action"))
        self.adaptation.update(s, cmd, d)
        out, err_m, cost = self._observe(read_state=before)

        outside = (s.pos_m.abs() > self.box_m).any(-1, keepdim=True)
        terminated = outside | ~torch.isfinite(cost)
        if self.params.max_tracking_error_m is not None:
            terminated |= err_m > float(self.params.max_tracking_error_m)
        truncated = (self.step_idx >= self.episode_len).unsqueeze(-1)
        penalty = self.params.reward.crash_penalty * terminated.to(self.dtype)
        if self.params.reward.rate_change:  # the previous command is kept only for this cost
            change = torch.linalg.vector_norm(cmd[:, 1:] - self.prev_cmd[:, 1:], dim=-1, keepdim=True)
            cost = cost + self.params.reward.rate_change * change
            self.prev_cmd.copy_(cmd)  # into its own buffer: cmd is also the simulator's
        reward = -torch.nan_to_num(cost, nan=0.0, posinf=0.0) - penalty
        out.update({"reward": reward, "done": terminated | truncated, "terminated": terminated, "truncated": truncated})
        return out

    def compile_kernels(self, sim: bool = True, **kwargs) -> TrackingEnv:
        """Fuse the integrator (``sim=True``), the observation/reward kernel and the adaptation
        update (if it supports it) with ``torch.compile`` (first call compiles, ~30 s on 2 cores;
        then several times faster at large N, and less dispatch overhead at N = 1)."""
        if sim:
            self.sim.compile(**kwargs)
        self._observe_kernel = compile_or_eager(observe_and_cost, **kwargs)
        if hasattr(self.adaptation, "compile"):
            self.adaptation.compile(**kwargs)
        return self

    def stagger_episodes(self) -> None:
        """From the next full reset, truncate each drone's first episode after a uniform random
        number of steps in [1, episode_steps], so training batches mix all phases of an episode
        instead of every drone being at the same step (later episodes have the full length)."""
        self._stagger_pending = True

    # -- conveniences ----------------------------------------------------------------------
    @property
    def hover_action(self) -> torch.Tensor:
        """Action that holds a level drone in hover, ``[N, 4]``."""
        a = torch.zeros(self.n, 4, device=self.device, dtype=self.dtype)
        a[:, 0] = self.params.quad.gravity_mps2
        return a

    def ref_lookahead_s(self) -> float:
        return float(self.ref_offsets[-1]) * self.dt_s

    def __repr__(self) -> str:
        return (
            f"TrackingEnv(num_envs={self.n}, horizon={self.horizon}, traj={type(self.traj).__name__}, "
            f"disturbance={type(self.disturbance).__name__}, adaptation={type(self.adaptation).__name__})"
        )


__all__ = ["TrackingEnv"]
