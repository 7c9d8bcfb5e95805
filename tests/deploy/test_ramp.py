"""The takeoff's and landing's reference (datt.deploy.runner.Ramp): a straight line at constant
speed from its start to its end over its duration, then held."""

import pytest
import torch

from datt.deploy.runner import Ramp


def test_the_ramp_starts_at_its_start_moves_linearly_and_holds_its_end():
    ramp = Ramp([0.0, 1.0, 0.0], [2.0, -1.0, 1.0], duration_s=2.0)
    t = torch.tensor([-0.5, 0.0, 0.5, 1.0, 2.0, 3.0], dtype=torch.float64)
    out = ramp.sample(2, t, None)
    assert out.shape == (2, 6, 3) and out.dtype == torch.float64
    expected = torch.tensor(
        [[0.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.5, 0.5, 0.25], [1.0, 0.0, 0.5], [2.0, -1.0, 1.0], [2.0, -1.0, 1.0]],
        dtype=torch.float64,
    )
    torch.testing.assert_close(out[0], expected)
    torch.testing.assert_close(out[1], expected)
    out[0, 0, 0] = 9.0  # each drone's rows are its own
    assert out[1, 0, 0] == 0.0


def test_a_zero_duration_ramp_is_at_its_end_at_once():
    ramp = Ramp([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], duration_s=0.0)
    out = ramp.sample(1, torch.tensor([0.0, 0.1], dtype=torch.float32), None)
    assert out.dtype == torch.float32
    assert out[0, :, 2].tolist() == pytest.approx([0.0, 1.0])


def test_the_ramp_keeps_its_end_points_in_double_precision():
    """Start and end are held as float64: a ramp sampled in float64 starts exactly at its start
    and holds its end to 1e-15 (float32 end points would be ~1e-8 off)."""
    start, end = [0.1, -0.3, 1.0 / 3.0], [0.7, 0.2, 2.0 / 3.0]
    ramp = Ramp(start, end, duration_s=1.0)
    assert ramp.start.dtype == ramp.end.dtype == torch.float64
    out = ramp.sample(1, torch.tensor([0.0, 2.0], dtype=torch.float64), None)
    assert out[0, 0].tolist() == start
    assert out[0, 1].tolist() == pytest.approx(end, abs=1e-15)
