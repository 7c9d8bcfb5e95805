"""``eval.protocol``: where the bank's episodes start, with what thrust, how long they run and
which steps count (the authors' protocol against its definition in datt.eval.protocol)."""

import math

import pytest
import torch
from omegaconf import OmegaConf

from datt.configuration import compose
from datt.control.base import Controller, HoverController
from datt.errors import ConfigError
from datt.eval.rollout import evaluate

G = 9.81
BANK = {"zigzag": [{"traj": "zigzag", "seed": 1000, "count": 40}], "star": [{"traj": "star", "seed": 0, "count": 1}]}


def cfg_with(protocol, *extra):
    cfg = compose("eval", [f"eval.protocol={protocol}", *extra])
    OmegaConf.set_struct(cfg, False)
    cfg.eval.bank = BANK
    return cfg


class Climb(Controller):
    """Full thrust, level: every drone leaves the box and exceeds any tracking-error limit."""

    def act(self, env, td):
        action = env.hover_action.clone()
        action[:, 0] = 30.0
        return action


def test_the_authors_protocol_starts_uniformly_within_half_a_metre_per_axis_from_the_same_points_for_every_condition():
    cfg = cfg_with("authors")
    starts = [
        evaluate(cfg, lambda env: HoverController(), dist, adapt, seed=3)["trace"].pos_m[:, 0]
        for dist, adapt in (("none", "none"), ("brownian", "privileged"))
    ]
    assert torch.equal(starts[0], starts[1])  # another disturbance draws from the env's stream, not the starts'
    other_seed = evaluate(cfg, lambda env: HoverController(), "none", "none", seed=4)["trace"].pos_m[:, 0]
    assert not torch.allclose(starts[0], other_seed)
    u = starts[0].flatten()  # 41 drones x 3 axes, U(-0.5, 0.5): mean 0, std 1/sqrt(12) = 0.289
    assert u.abs().max() <= 0.5
    assert u.min() < -0.4 and u.max() > 0.4  # both tails reached
    assert abs(u.mean().item()) < 0.08 and 0.23 < u.std().item() < 0.35


@pytest.mark.parametrize("trained_from", [[], ["env.quad.initial_thrust_mps2=0.0"]])
def test_the_project_protocol_starts_on_the_reference_at_hover_thrust(trained_from):
    """Also for a policy trained from zero-thrust starts: the start belongs to the protocol."""
    cfg = cfg_with("project", *trained_from)
    trace = evaluate(cfg, lambda env: HoverController(), "none", "none", seed=3)["trace"]
    assert torch.equal(trace.pos_m[:, 0], trace.ref_m[:, 0])
    assert trace.pos_m[:, 1, 2].abs().max() < 1e-6  # hover thrust from the start: no drop


def test_the_authors_protocol_starts_at_zero_thrust_for_five_hundred_counted_steps():
    cfg = cfg_with("authors", "env.episode_steps=100")
    trace = evaluate(cfg, lambda env: HoverController(), "none", "none", seed=0)["trace"]
    assert trace.err_m.shape[1] == 500  # their t_end = 500 dt, whatever env.episode_steps says
    dt = float(cfg.env.dt_s)
    drop = trace.pos_m[:, 1, 2] - trace.pos_m[:, 0, 2]  # first step: no thrust, free fall from rest
    assert torch.allclose(drop, torch.full_like(drop, -G * dt * dt / 2), atol=1e-6)


def test_the_authors_protocol_counts_every_step_of_every_episode_and_still_counts_crashes():
    res = {p: evaluate(cfg_with(p), lambda env: Climb(), "none", "none", seed=0) for p in ("project", "authors")}
    project, authors = res["project"]["groups"]["zigzag"], res["authors"]["groups"]["zigzag"]
    assert project["crashes"] == authors["crashes"] == 40
    assert math.isnan(project["mean_m"])  # every episode crashed: left out, the row fails
    trace = res["authors"]["trace"]
    expect = trace.err_m[:40].mean(1)  # every step, also after leaving the box
    assert authors["mean_m"] == pytest.approx(expect.mean().item(), rel=1e-5)
    assert (trace.crashed_at[:40] < 100).all() and authors["mean_m"] > 10.0
    assert authors["protocol"] == "authors" and project["protocol"] == "project"


def test_an_unknown_protocol_is_refused_in_one_line():
    with pytest.raises(ConfigError, match=r"eval.protocol: unknown value 'paper'; allowed: project, authors"):
        evaluate(cfg_with("paper"), lambda env: HoverController(), "none", "none")


def _probe(monkeypatch, **change):
    """The project protocol with one field changed, as the protocol ``probe``."""
    import dataclasses

    from datt.eval import protocol as protocol_module

    probe = dataclasses.replace(protocol_module.PROTOCOLS["project"], **change)
    monkeypatch.setitem(protocol_module.PROTOCOLS, "probe", probe)
    monkeypatch.setattr("datt.eval.schema.PROTOCOLS", protocol_module.PROTOCOLS, raising=False)
    return cfg_with("project", "env.max_tracking_error_m=0.3")


def _run(cfg, name, controller=HoverController):
    cfg = cfg.copy()
    cfg.eval.protocol = name
    return evaluate(cfg, lambda env: controller(), "none", "none", seed=2)


def test_each_protocol_setting_alone_changes_what_it_claims_and_nothing_else(monkeypatch):
    """One field of the project protocol at a time: the start offset moves only the starts, the
    start thrust only the first step's drop, the episode length only the length, counting every
    step only which episodes enter the mean, and the error limit off only whether a drone far off
    its reference stops (each compared with the project protocol itself on the same seed)."""
    base = _run(cfg_with("project", "env.max_tracking_error_m=0.3"), "project")
    bt = base["trace"]

    cfg = _probe(monkeypatch, init_pos_range_m=0.5)
    t = _run(cfg, "probe")["trace"]
    assert (t.pos_m[:, 0] - t.ref_m[:, 0]).abs().max() > 0.3 and t.err_m.shape == bt.err_m.shape
    assert t.pos_m[:, 1, 2].sub(t.pos_m[:, 0, 2]).abs().max() < 1e-6  # still hover thrust: no drop

    t = _run(_probe(monkeypatch, initial_thrust_mps2=0.0), "probe")["trace"]
    assert torch.equal(t.pos_m[:, 0], bt.pos_m[:, 0])  # the same starts
    drop = t.pos_m[:, 1, 2] - t.pos_m[:, 0, 2]
    assert torch.allclose(drop, torch.full_like(drop, -G * 0.02 * 0.02 / 2), atol=1e-6)

    t = _run(_probe(monkeypatch, episode_steps=37), "probe")["trace"]
    assert t.err_m.shape[1] == 37 and torch.equal(t.pos_m[:, 0], bt.pos_m[:, 0])

    crashing = _run(cfg_with("project", "env.max_tracking_error_m=0.3"), "project", Climb)["groups"]["zigzag"]
    every = _run(_probe(monkeypatch, count_every_step=True), "probe", Climb)
    assert math.isnan(crashing["mean_m"]) and crashing["crashes"] == 40
    assert every["groups"]["zigzag"]["crashes"] == 40 and math.isfinite(every["groups"]["zigzag"]["mean_m"])

    kept = _run(_probe(monkeypatch, terminate_on_error=False), "probe", Climb)["trace"]
    stopped = _run(cfg_with("project", "env.max_tracking_error_m=0.3"), "project", Climb)["trace"]
    # the error limit off: climbing drones fly on past 0.3 m of error; on, they stop there
    assert (stopped.crashed_at[:40] < kept.crashed_at[:40]).all()
    assert kept.err_m[:40, -1].min() > 0.3


def test_a_drone_that_climbs_or_falls_away_diverges_and_one_that_holds_its_start_does_not():
    """Under the authors' protocol (no termination on error) a drone climbing at full thrust
    leaves its reference, and so does an open-loop hover from their zero-thrust start (it keeps
    the velocity of its first fall): every episode diverged and the run failed. The same hover
    from the project's start holds its start point, 0.2-0.8 m off a zigzag: under the 1 m limit."""
    from datt.eval.metrics import run_failed

    climb = _run(cfg_with("authors"), "authors", Climb)["groups"]["zigzag"]
    fall = _run(cfg_with("authors"), "authors")["groups"]["zigzag"]
    hover = _run(cfg_with("project"), "project")["groups"]["zigzag"]
    for away in (climb, fall):
        assert away["diverged"] == away["episodes"] == 40 and run_failed(away)
    assert hover["diverged"] == 0 and not run_failed(hover) and 0.2 < hover["mean_m"] < 0.8
    strict = cfg_with("project", "eval.diverged_error_m=0.05")
    assert _run(strict, "project")["groups"]["zigzag"]["diverged"] == 40  # the limit is the config's
