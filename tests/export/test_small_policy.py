"""``policy=small``: the network a Crazyflie can afford at 500 Hz (docs/training.md, "A policy for
the vehicle"). Its cost is counted from the exported layers, and its C computes the torch action."""

from __future__ import annotations

import numpy as np
import pytest

from datt.configuration import compose
from datt.export import export_spec, reference_action, write_c
from tests.conftest import train_tiny_policy
from tests.export.test_c_export import (
    build,
    c_actions,
    pytestmark,  # noqa: F401  (no gcc: skipped, as the C export's tests)
    random_observations,
)


@pytest.fixture(scope="module")
def specs(tmp_path_factory):
    """(spec, controller, merged config) of a tiny-trained ``policy=small`` and of the paper's."""
    out = {}
    for name in ("small", "datt"):
        run = tmp_path_factory.mktemp(name)
        checkpoint = train_tiny_policy(run, f"policy={name}", "env.obs.action_history=2")
        out[name] = export_spec(compose("export", [f"checkpoint={checkpoint}"]))
    return out


def test_the_small_network_is_the_layers_its_file_names(specs):
    spec = specs["small"][0]
    assert [w.shape for w, _ in spec.convs] == [(8, 3, 3)]  # one 8-channel convolution, kernel 3
    assert spec.proj[0].shape == (16, 8 * spec.horizon)  # a 16-wide embedding
    assert [w.shape[0] for w, _ in spec.mlp] == [64, 48]  # two hidden layers
    assert spec.mlp[0][0].shape[1] == spec.state_dim + 16 + 3  # state, embedding, d-hat


def test_the_small_network_costs_about_a_quarter_of_the_papers(specs):
    """Counted as the C runs it: 672 conv + 1,280 embedding + 2,560 + 3,072 MLP + 192 head MACs
    at H = 10 with two commands of history, against the paper network's 32,832."""
    small, paper = specs["small"][0].macs, specs["datt"][0].macs
    assert (small, paper) == (7776, 32832)


def test_the_small_policys_c_computes_the_torch_action(specs, tmp_path):
    spec, controller, merged = specs["small"]
    write_c(spec, tmp_path)
    lib = build(tmp_path, "libsmall.so")
    obs = random_observations(500, spec.horizon, spec.action_history, seed=4)
    got = c_actions(lib, spec, obs)
    expect = reference_action(controller, merged.env.obs, obs).numpy()
    assert np.abs(got - expect).max() <= 8 * np.spacing(np.abs(expect).max())
