"""``deploy.vehicle``: the preset's numbers reach the host's thrust map, the simulated vehicle's
motors and its rate loop; an explicit setting wins; an unknown preset is one line."""

from __future__ import annotations

import pytest

from datt.configuration import compose
from datt.deploy.schema import deploy_params
from datt.errors import ConfigError
from datt.sim.vehicles import VEHICLES


@pytest.mark.parametrize("name", sorted(VEHICLES))
def test_the_preset_fills_the_thrust_map_and_the_simulated_vehicle(name):
    v = VEHICLES[name]
    params, _, _, thrust = deploy_params(compose("deploy", [f"deploy.vehicle={name}"]).deploy)
    assert (thrust.mass_kg, thrust.thrust_max_n) == (v.mass_kg, v.thrust_max_n)
    assert params.server["vehicle"] == name


def test_the_default_vehicle_is_a_stock_crazyflie_on_its_firmware_rate_loop():
    from datt.deploy.sim import SimCrazyflie, SimCrazyflieParams
    from datt.deploy.sim.motors import MotorParams

    cfg = compose("deploy", [])
    assert cfg.deploy.vehicle == "cf21" and cfg.deploy.server.rate_loop is None
    assert compose("deploy", ["deploy=crazyflie"]).deploy.vehicle == "cf21"
    assert SimCrazyflie(SimCrazyflieParams(motors=MotorParams(vehicle="cf21"))).rate_loop == "firmware"
    upgrade = SimCrazyflie(SimCrazyflieParams(motors=MotorParams(vehicle="cf21_upgrade")))
    assert upgrade.rate_loop == "pi_first_order" and upgrade.motors.p.thrust_max_n == 0.18
    forced = SimCrazyflie(SimCrazyflieParams(rate_loop="pi_first_order", motors=MotorParams(vehicle="cf21")))
    assert forced.rate_loop == "pi_first_order"


def test_an_explicit_number_wins_over_the_preset():
    params, _, _, thrust = deploy_params(
        compose("deploy", ["deploy.vehicle=cf21_upgrade", "deploy.thrust.mass_kg=0.045"]).deploy
    )
    assert thrust.mass_kg == 0.045 and thrust.thrust_max_n == 0.18


def test_an_unknown_preset_is_one_line_naming_the_presets():
    with pytest.raises(ConfigError, match=r"^deploy\.vehicle: unknown value 'cf3'; allowed: cf21, cf21_upgrade$"):
        deploy_params(compose("deploy", ["deploy.vehicle=cf3"]).deploy)


@pytest.mark.parametrize("name", sorted(VEHICLES))
def test_the_training_sides_firmware_loop_flies_the_presets_vehicle(name):
    """``env.quad.vehicle`` picks the firmware loop's constants; its mass is the preset's unless given."""
    import torch

    from datt.sim.quadrotor import Quadrotor, QuadrotorParams

    quad = Quadrotor(2, QuadrotorParams(rate_model="firmware", vehicle=name), dt_s=0.02)
    v = VEHICLES[name]
    assert quad.firmware.vehicle is v and quad.firmware.mass_kg == v.mass_kg
    assert quad.firmware.command_per_mps2 == pytest.approx(v.mass_kg / 4 / v.thrust_max_n * 65535)
    heavier = Quadrotor(1, QuadrotorParams(rate_model="firmware", vehicle=name, vehicle_mass_kg=0.05), dt_s=0.02)
    assert heavier.firmware.mass_kg == 0.05
    assert torch.isfinite(quad.state.pos_m).all()


def test_the_paper_vehicle_has_the_papers_thrust_to_weight():
    """§5: 'weighs 40 g and has a thrust-to-weight ratio of slightly under 2'; the stock one is
    limited by the legacy commander's MAX_THRUST to a ceiling of 12.9 m/s² at 34 g."""
    assert 1.8 < VEHICLES["cf21_upgrade"].thrust_to_weight() < 2.0
    assert VEHICLES["cf21"].ceiling_mps2() == pytest.approx(12.925, abs=1e-3)


@pytest.mark.parametrize("name", sorted(VEHICLES))
def test_every_preset_has_a_policy_per_mode_that_is_shipped(name):
    from datt.paths import resolve_path
    from datt.tasks.deploy import default_checkpoint, resolve_checkpoint

    for onboard in (False, True):
        path = default_checkpoint(name, onboard)
        assert resolve_path(path).is_file(), path
        cfg = compose("deploy", [f"deploy.vehicle={name}", f"deploy.onboard={str(onboard).lower()}"])
        resolve_checkpoint(cfg)
        assert cfg.checkpoint == path


@pytest.mark.parametrize(
    "kind, track_steps, counted",
    [
        ("landed", 500, "landed"),
        ("landed_onboard", 500, "landed"),
        ("landed_early", 357, "landed early"),  # a LAND decision in TRACK (sinking, stale mocap ...)
        ("landed_early", 0, "refused"),  # landed before TRACK: the hover trim's limit
        ("refused_reference", 0, "refused"),
        ("refused", 0, "refused"),
        ("killed", 120, "killed"),
        ("link_lost", 10, "link_lost"),
    ],
)
def test_the_transfer_grid_counts_each_outcome_where_it_belongs(kind, track_steps, counted):
    from datt.tasks.transfer import verdict

    assert verdict(kind, track_steps) == counted


def test_a_grid_cell_is_the_presets_vehicle_made_worse():
    from datt.tasks.transfer import cell_conditions

    cell = cell_conditions("cf21_upgrade", 60, 15, -10, 5)
    assert cell == {
        "deploy.vehicle": "cf21_upgrade",
        "deploy.server.radio_latency_s": 0.03,  # each way
        "deploy.server.mass_kg": pytest.approx(0.046),
        "deploy.server.thrust_gain": 0.9,
        "deploy.server.radio_loss": 0.05,
    }


# the rate model a training run uses for a preset's rate loop: the firmware's own, or for the
# authors' PI loop (which no simulator has) the first-order model with half the drones second-order
TRAINING_RATE_MODEL = {"firmware": "firmware", "pi_first_order": "mixed"}


@pytest.mark.parametrize(
    "command, name",
    [
        ("experiment=deploy_smooth", "cf21"),
        ("experiment=deploy_radio", "cf21"),
        ("experiment=deploy_radio vehicle=cf21_upgrade", "cf21_upgrade"),
        *((f"vehicle={n}", n) for n in VEHICLES),
    ],
)
def test_a_deploy_policys_training_vehicle_is_its_presets(command, name):
    """The training side of a preset's policy: the preset's firmware-loop constants
    (env.quad.vehicle), its off-board ceiling (MAX_THRUST on the flying mass, to the YAML's
    two decimals) and a rate model for its rate loop."""
    cfg = compose("train", command.split())
    assert cfg.env.quad.vehicle == name
    assert cfg.env.quad.max_thrust_mps2 == pytest.approx(VEHICLES[name].ceiling_mps2(), abs=0.006)
    assert cfg.env.quad.rate_model == TRAINING_RATE_MODEL[VEHICLES[name].rate_loop]


def test_every_preset_has_a_training_vehicle_and_only_those():
    """``vehicle=<preset>`` of train.py exists for every preset and for nothing else."""
    from datt.paths import PACKAGE_DIR

    names = {p.stem for p in (PACKAGE_DIR / "conf" / "vehicle").glob("*.yaml")}
    assert names == set(VEHICLES)
