"""The d̂ figure plots what its definition says: per world axis, the disturbance and the estimate of
the first reference of each group, over the steps it flew, against time in seconds."""

from __future__ import annotations

import numpy as np
import torch

from datt.eval.plots import disturbance_estimate_figure, plot_disturbance_estimate
from datt.eval.rollout import Trace


def trace_of(n: int = 3, steps: int = 50) -> Trace:
    g = torch.Generator().manual_seed(0)
    d = torch.randn(n, steps, 3, generator=g)
    return Trace(
        pos_m=torch.zeros(n, steps + 1, 3),
        ref_m=torch.zeros(n, steps + 1, 3),
        err_m=torch.zeros(n, steps),
        action=torch.zeros(n, steps, 4),
        d_mps2=d,
        d_hat=d + 0.1 * torch.randn(n, steps, 3, generator=g),
        crashed_at=torch.tensor([steps, 20, steps]),
        step_ms=[],
    )


def test_each_panel_is_one_axis_of_the_first_reference_of_its_group():
    trace = trace_of()
    fig = disturbance_estimate_figure(trace, ["zigzag", "poly"], [1, 2], dt_s=0.02)
    axes = np.array(fig.axes).reshape(3, 2)
    for col, first in enumerate([0, 1]):  # group "poly" starts at drone 1, which crashed at step 20
        stop = int(trace.crashed_at[first])
        for k in range(3):
            d_line, d_hat_line = axes[k, col].lines
            assert np.allclose(d_line.get_ydata(), trace.d_mps2[first, :stop, k].numpy())
            assert np.allclose(d_hat_line.get_ydata(), trace.d_hat[first, :stop, k].numpy())
            assert np.allclose(d_line.get_xdata(), np.arange(1, stop + 1) * 0.02)
    assert axes[0, 1].get_title() == "poly #0" and axes[2, 0].get_ylabel() == "z (m/s²)"


def test_the_figure_is_written(tmp_path):
    path = plot_disturbance_estimate(trace_of(), ["zigzag"], [3], 0.02, tmp_path / "dhat.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
