"""The controller a config names (``controller=<option>``), ready to fly."""

from __future__ import annotations

import torch
from omegaconf import DictConfig, OmegaConf

from datt.configuration import command_overrides, hydra_choice, instantiate_option, with_options
from datt.control.datt import DattController
from datt.envs.params import OBS_LAYOUT_KEYS
from datt.errors import ConfigError
from datt.policies.loading import load_actor


def build_controller(cfg: DictConfig):
    """``(controller, config to fly it under, labels)`` for ``cfg.controller``.

    Options without ``_target_`` (datt, datt_l1, datt_rma) load the policy from ``checkpoint``; its
    observation layout (horizon, ablations, command history) comes from its training config, the
    observation noise does not (that belongs to where it flies). An ``adaptation`` key
    in the controller option fixes the estimator it flies with (l1_pid, l1_mppi, datt_l1, ...).
    """
    node = OmegaConf.to_container(cfg.controller, resolve=True)
    name, forced = str(node.pop("name")), node.pop("adaptation", None)
    if forced:
        refuse_unused_adaptation_overrides(name, str(forced))
    # a resolved, non-struct copy, with the controller's own estimator if it fixes one
    merged = with_options(cfg, **({"adaptation": str(forced)} if forced else {}))
    labels = {
        "controller": name,
        "disturbance": hydra_choice("disturbance"),
        "adaptation": forced or hydra_choice("adaptation"),
    }
    if "_target_" in node:
        return instantiate_option(OmegaConf.create({"controller": node}), "controller"), merged, labels
    actor, train_cfg, data = load_actor(cfg.checkpoint)
    refuse_overrides_the_checkpoint_fixes(cfg, train_cfg)
    actor.to(torch.device(cfg.env.device))  # beside the env's drones (env.device)
    layout = {key: train_cfg.env.obs[key] for key in OBS_LAYOUT_KEYS if key in train_cfg.env.obs}
    merged = OmegaConf.merge(merged, {"horizon": train_cfg.horizon, "env": {"obs": layout}})
    OmegaConf.set_struct(merged, False)
    # trained behind the state predictor (not part of the layout: it changes which state the policy
    # expects, which deploy.py's own predictor then supplies off-board)
    behind = bool(train_cfg.env.obs.get("predict_latency", False))
    labels = {**labels, "checkpoint": str(cfg.checkpoint), "frames": int(data["frames"]), "predict_latency": behind}
    return DattController(actor, frozen=True), merged, labels


def fixed_by_checkpoint(key: str) -> bool:
    """Whether a policy checkpoint fixes the dotted ``key``: its horizon, its observation layout
    (``env.obs.<OBS_LAYOUT_KEYS>``) and its network (``policy.*``): a policy flies as trained."""
    return key == "horizon" or key.startswith("policy.") or key in {f"env.obs.{k}" for k in OBS_LAYOUT_KEYS}


def refuse_overrides_the_checkpoint_fixes(cfg: DictConfig, train_cfg: DictConfig) -> None:
    """An override on the command line that sets what the checkpoint fixes
    (:func:`fixed_by_checkpoint`) to another value than the policy was trained with is refused in
    one line; it would be dropped (the policy flies its own layout), and the run would record a
    setting it did not fly."""
    for text in command_overrides() or []:  # none outside Hydra: the caller composed the config itself
        key = text.lstrip("+~").partition("=")[0]
        if not fixed_by_checkpoint(key):
            continue
        asked = OmegaConf.select(cfg, key, default=None)
        trained = OmegaConf.select(train_cfg, key, default=None)
        if asked != trained:
            raise ConfigError(
                f"{key}: the checkpoint was trained with {key}={trained} and flies as trained; drop {text!r}, "
                f"or pass a checkpoint trained with {key}={asked}"
            )


def require_current_state_timing(merged: DictConfig, who: str) -> None:
    """A vehicle feeds the policy its newest state estimate: refuse, in one line, a policy trained
    to read the state one step old (``env.obs.timing=authors``)."""
    if merged.env.obs.timing != "project":
        raise ConfigError(
            f"checkpoint: trained with env.obs.timing={merged.env.obs.timing} (the state one step old); "
            f"{who} feeds the newest state; allowed: a policy trained with env.obs.timing=project"
        )


def refuse_unused_adaptation_overrides(controller: str, forced: str) -> None:
    """A controller option that fixes its estimator (``adaptation: l1`` in ``controller/datt_l1``)
    would fly without the command line's ``adaptation`` settings: refuse them in one line rather
    than drop them (what a run records must be what it ran)."""
    for text in command_overrides() or []:  # none outside Hydra: the caller composed the config itself
        key, _, value = text.lstrip("+~").partition("=")
        if key == "adaptation" and value == forced:
            continue
        if key == "adaptation" or key.startswith("adaptation."):
            raise ConfigError(
                f"{key}: controller={controller} flies with its own estimator (adaptation={forced}) and would "
                f"not use {text!r}; drop it, or choose datt, pid or mppi with adaptation=<option> and your settings"
            )
