"""Disturbance-estimate sources for the policy input ``d_hat`` (world frame, m/s², ``[N, 3]``).

Protocol shared by every option of ``conf/adaptation/`` (and by L1/RMA estimators):

* ``bind(n, dt_s, gravity_mps2, device, dtype)`` once;
* ``reset(idx, true_d_mps2, state)`` when drones ``idx`` start an episode (``true_d_mps2 [N, 3]``
  or None; ``state`` the sim/measured state of all N drones, or None);
* ``update(state, cmd, true_d_mps2)`` after each sim step, returns ``d_hat [N, 3]``. ``state`` is
  the sim's :class:`~datt.sim.QuadState` (or measured state on hardware), ``cmd [N, 4]`` the
  command (thrust_mps2, body rates) sent this step, ``true_d_mps2`` the simulator's disturbance
  for the next step, or ``None`` where it is unknown (hardware).
"""

from __future__ import annotations

import torch
from torch import Tensor


class Adaptation:
    """Base class: ``d_hat = 0`` (``adaptation=none``, the paper's "d̂ = 0" row)."""

    uses_true_disturbance = False

    def bind(self, n: int, dt_s: float, gravity_mps2: float, device, dtype) -> None:
        self.n = n
        self.dt_s = dt_s
        self.gravity_mps2 = gravity_mps2
        self.d_hat = torch.zeros(n, 3, device=device, dtype=dtype)

    def reset(self, idx: Tensor, true_d_mps2: Tensor | None = None, state=None) -> None:
        self.d_hat[idx] = 0.0

    def update(self, state, cmd: Tensor, true_d_mps2: Tensor | None) -> Tensor:
        return self.d_hat


ZeroEstimate = Adaptation


class Privileged(Adaptation):
    """``d_hat = d``: the simulator's true disturbance (training default, paper §4.2)."""

    uses_true_disturbance = True

    def reset(self, idx: Tensor, true_d_mps2: Tensor | None = None, state=None) -> None:
        if true_d_mps2 is None:
            raise RuntimeError("adaptation=privileged needs the true disturbance; use l1 or rma outside simulation")
        self.d_hat[idx] = true_d_mps2[idx]

    def update(self, state, cmd: Tensor, true_d_mps2: Tensor | None) -> Tensor:
        if true_d_mps2 is None:
            raise RuntimeError("adaptation=privileged needs the true disturbance; use l1 or rma outside simulation")
        self.d_hat.copy_(true_d_mps2)
        return self.d_hat
