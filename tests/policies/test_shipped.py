"""The shipped checkpoint loads from the package and evaluates to the numbers recorded beside it
(``checkpoints/datt_h10_metrics.json``, written by the run that produced it)."""

import json

import pytest

from datt.configuration import compose, upgrade_saved_config
from datt.control.factory import build_controller
from datt.eval.rollout import evaluate
from datt.paths import PACKAGE_DIR, resolve_path
from datt.sim.vehicles import VEHICLES


def test_shipped_checkpoint_is_found_from_any_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert resolve_path("checkpoints/datt_h10.pt") == PACKAGE_DIR / "checkpoints" / "datt_h10.pt"


def test_shipped_policy_evaluates_to_its_recorded_numbers(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    recorded = json.loads((PACKAGE_DIR / "checkpoints" / "datt_h10_metrics.json").read_text())
    clean = recorded["conditions"]["clean"]["groups"]
    cfg = compose("eval", ["controller=datt", "checkpoint=checkpoints/datt_h10.pt"])
    controller, merged, _ = build_controller(cfg)
    res = evaluate(merged, lambda env: controller, "none", "none", seed=0)
    assert set(res["groups"]) == set(clean) == {"zigzag", "zigzag_fast", "smooth", "star"}
    for group in clean:
        assert res["groups"][group]["crashes"] == 0
        assert res["groups"][group]["mean_m"] == pytest.approx(clean[group]["mean_m"], abs=2e-4), group


# Config keys added after the shipped checkpoints were trained -> the values that reproduce what
# the code did before they existed.
ADDED_SINCE: dict[str, tuple] = {
    "env.obs.timing": ("project",),
    "curriculum.fixed_ref": ("steps",),
    # the firmware rate model's vehicle: read only under env.quad.rate_model=firmware
    "env.quad.vehicle_mass_kg": (0.034, None),
    "env.quad.vehicle": ("cf21",),  # the vehicle preset (datt.sim.vehicles): its numbers are the former constants
    "env.quad.motor_time_constant_s": (0.03,),
    "env.obs.predict_latency": (False,),
    "env.obs.predict_latency_error_steps": (0,),
    # the thrust map trimmed to the vehicle (experiment=deploy_trimmed): off, and its error unused then
    "env.quad.thrust_map_trimmed": (False,),
    "env.quad.trim_error_spread": (0.0,),
    # the cost on the rate command's change (experiment=deploy_smooth): the paper's reward without it
    "env.reward.rate_change": (0.0,),
    # commands lost on the way (experiment=deploy_radio): none
    "env.quad.command_loss_max": (0.0,),
}


def drop_added_keys(trained: dict, expected: dict) -> None:
    """Remove from ``expected`` the keys added since ``trained`` was written (those the checkpoint
    lacks), checking that today's value is one that keeps its behaviour."""
    for path, values in ADDED_SINCE.items():
        *parents, name = path.split(".")
        have, want = trained, expected
        for part in parents:
            if part not in want:
                break
            have, want = have[part], want[part]
        else:
            if name not in have:  # a checkpoint trained before the key existed
                assert want.pop(name) in values, path
    for side in (expected, trained):  # null means the preset's mass; older checkpoints wrote it out
        quad = side["env"]["quad"]
        if "vehicle_mass_kg" in quad and quad["vehicle_mass_kg"] is None:
            quad["vehicle_mass_kg"] = VEHICLES[quad.get("vehicle", "cf21")].mass_kg


@pytest.mark.parametrize(
    "command, checkpoint, parent",
    [
        ("experiment=deploy", "checkpoints/datt_h10_deploy.pt", "checkpoints/datt_h10_train_mix.pt"),
        ("experiment=deploy_firmware", "checkpoints/datt_h10_firmware.pt", "checkpoints/datt_h10_deploy.pt"),
        ("experiment=deploy_predictor", "checkpoints/datt_h10_predictor.pt", "checkpoints/datt_h10_firmware.pt"),
        ("experiment=deploy_smooth", "checkpoints/datt_h10_smooth.pt", "checkpoints/datt_h10_predictor.pt"),
        ("experiment=deploy_radio", "checkpoints/datt_h10_radio.pt", "checkpoints/datt_h10_smooth.pt"),
        ("experiment=deploy_radio vehicle=cf21", "checkpoints/datt_h10_radio.pt", "checkpoints/datt_h10_smooth.pt"),
        (
            "experiment=deploy_radio vehicle=cf21_upgrade",
            "checkpoints/datt_h10_upgrade.pt",
            "checkpoints/datt_h10_smooth.pt",
        ),
    ],
)
def test_deploy_grade_checkpoint_is_the_output_of_its_experiment(command, checkpoint, parent):
    """Each deploy-grade checkpoint came from ``python train.py <command>`` as it is configured
    now: its last stage's whole config (env, policy, algo, references, disturbance, adaptation) is
    the one the command composes, and it starts from ``parent``."""
    from omegaconf import OmegaConf

    from datt.checkpoint import load_checkpoint
    from datt.tasks.stages import stage_config, stage_plan

    cfg = compose("train", command.split())
    assert cfg.train.init_from == parent
    if cfg.train.stages is None:  # one run: its own config, its whole budget
        plan, expected = [("", cfg.train.total_frames, {})], OmegaConf.to_container(cfg, resolve=True)
    else:
        plan = stage_plan(cfg)
        expected = OmegaConf.to_container(stage_config(cfg, len(plan) - 1, plan, "previous/last.pt"), resolve=True)
    data = load_checkpoint(resolve_path(checkpoint))
    trained = OmegaConf.to_container(upgrade_saved_config(OmegaConf.create(data["config_yaml"])), resolve=True)
    drop_added_keys(trained, expected)  # keys added after the checkpoint was trained
    for key in ("env", "policy", "algo", "traj", "disturbance", "adaptation", "horizon", "seed"):
        assert trained[key] == expected[key], key
    batch = cfg.algo.num_envs * cfg.algo.rollout_steps
    assert data["frames"] == -(-plan[-1][1] // batch) * batch  # the last stage's steps, in whole batches


@pytest.mark.parametrize(
    "checkpoint, overrides",
    [
        ("checkpoints/datt_h10.pt", []),
        # the deploy-grade policy's parent: the authors' zigzags only, hover-thrust starts, 30 M steps
        (
            "checkpoints/datt_h10_train_mix.pt",
            ["traj=train_mix", "env.quad.initial_thrust_mps2=null", "train.total_frames=30000000"],
        ),
    ],
)
def test_shipped_checkpoint_is_the_output_of_python_train_py(checkpoint, overrides):
    """``checkpoints/datt_h10.pt`` is what ``python train.py`` trains with today's defaults (and
    ``datt_h10_train_mix.pt`` what it trains with two overrides): its whole config (env, policy,
    algo, references, curriculum, disturbance, adaptation, budget) is the one they compose, it has
    no parent, and it ran the whole budget."""
    from omegaconf import OmegaConf

    from datt.checkpoint import load_checkpoint

    cfg = OmegaConf.to_container(compose("train", overrides), resolve=True)
    data = load_checkpoint(resolve_path(checkpoint))
    trained = OmegaConf.to_container(upgrade_saved_config(OmegaConf.create(data["config_yaml"])), resolve=True)
    drop_added_keys(trained, cfg)  # keys added after the checkpoint was trained
    keys = ("env", "policy", "algo", "traj", "curriculum", "disturbance", "adaptation", "horizon", "seed", "budget")
    for key in keys:
        assert trained[key] == cfg[key], key
    # the train node but the keys that change how a run is carried out, not what it trains
    bookkeeping = ("progress", "progress_every_s", "checkpoint_every")
    assert {k: v for k, v in trained["train"].items() if k not in bookkeeping} == {
        k: v for k, v in cfg["train"].items() if k not in bookkeeping
    }
    assert data["lineage"] == [] and trained["train"]["init_from"] is None
    batch = cfg["algo"]["num_envs"] * cfg["algo"]["rollout_steps"]
    assert data["frames"] == -(-cfg["train"]["total_frames"] // batch) * batch
