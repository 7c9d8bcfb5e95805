"""Each entry point's ``--help``: what it does, the overrides most runs use, examples, and only the
config groups its own config selects (with their options). Hydra's generic page, which lists
every group of the tree on every command, stays behind ``--hydra-help``."""

from __future__ import annotations

from dataclasses import dataclass, field

from omegaconf import OmegaConf

from datt.configuration import available_options, conf_dir


@dataclass(frozen=True)
class Usage:
    """One entry point's help: ``about`` (one sentence), ``overrides`` (override, what it does),
    ``examples`` (command lines) and ``extra_groups`` (groups added with ``+group=``)."""

    about: str
    overrides: tuple[tuple[str, str], ...]
    examples: tuple[str, ...]
    extra_groups: tuple[str, ...] = field(default=())


USAGE = {
    "train": Usage(
        "Train a DATT policy with PPO in the batched quadrotor simulator (defaults: the paper's main policy, "
        "H = 10, on the CPU); the run dir gets checkpoints, metrics.csv/json, plots and train.log.",
        (
            ("horizon=<int>", "the reference horizon H the policy sees (paper: 10)"),
            ("budget=<float>", "scale the run's length (train.total_frames) for a small machine"),
            ("seed=<int>", "the run's seed"),
            ("resume=true | resume=<run dir>", "carry on an interrupted run (the newest, or that one)"),
            ("logger=wandb", "also log to wandb (offline: no login; wandb sync later)"),
        ),
        (
            "python train.py",
            "python train.py budget=0.2 seed=1",
            "python train.py -m +sweep=ablation                  # a paper table's sweep (tables.py ablation)",
            "python train.py +search=lr                       # an Optuna search (pip install -e '.[sweep]')",
            "python train.py experiment=deploy_radio vehicle=cf21_upgrade",
        ),
        ("sweep", "search"),
    ),
    "eval": Usage(
        "Evaluate a controller over the seeded reference bank: mean tracking error per reference group, "
        "crashes and inference time, in metrics.json / metrics.csv and plots.",
        (
            ("checkpoint=<run dir or .pt>", "the policy (default: the shipped datt_h10.pt)"),
            ("controller=<option>", "datt, datt_l1, datt_rma, pid, mppi, l1_pid, l1_mppi ..."),
            ("disturbance=<option> adaptation=<option>", "the condition (default: none, none)"),
            ("eval.seeds=[0,1,2]", "the bank at several seeds (each one's result is kept as it finishes)"),
            ("eval.protocol=authors", "the authors' evaluation protocol instead of the project's"),
        ),
        (
            "python eval.py checkpoint=outputs/train/<run>",
            "python eval.py controller=pid",
            "python eval.py disturbance=brownian adaptation=l1 'eval.seeds=[0,1,2]'",
        ),
    ),
    "fit_rma": Usage(
        "Fit an RMA adapter (d-hat from the state-action history) to a trained policy, then evaluate the "
        "policy with it, with L1, with the privileged d and with none.",
        (
            ("base_checkpoint=<.pt>", "the frozen policy to adapt (default: the shipped datt_h10.pt)"),
            ("rma.iterations=<int>", "the fit's length"),
            ("budget=<float>", "scale rma.iterations"),
            ("eval.seeds=[0,1,2]", "evaluate at several seeds"),
            ("logger=wandb", "also log to wandb"),
        ),
        ("python fit_rma.py", "python fit_rma.py base_checkpoint=outputs/train/<run>/last.pt budget=0.5"),
    ),
    "tables": Usage(
        "Build a paper table (markdown, LaTeX, CSV, plots) from its sweep's runs, with the paper's figures "
        "beside ours; run=true runs the sweep first.",
        (
            ("<table>", "main, ablation, ablation_authors, ablation_sb3, horizon, rma, wind (the first argument)"),
            ("runs=<sweep dir>", "the runs to read (default: the newest sweep of that table)"),
            ("run=true", "run the table's sweep, then build the table"),
            ("out_dir=<dir>", "where the table's files go"),
            ("logger=wandb", "the table as a numeric wandb Table in its sweep's group"),
        ),
        (
            "python tables.py ablation",
            "python tables.py horizon run=true budget=0.1",
            "python tables.py main runs=<dir>",
        ),
    ),
    "deploy": Usage(
        "Fly a policy: on the simulated Crazyflie (default, speaks the real radio protocol) or a real one "
        "(deploy=crazyflie); preflight, arm, take off, hover check, track the reference, land.",
        (
            ("deploy=crazyflie deploy.uri=radio://0/80/2M/E7E7E7E7E7", "a real vehicle over a Crazyradio"),
            ("deploy.vehicle=cf21 | cf21_upgrade", "the vehicle preset that flies (docs/deploy.md)"),
            ("deploy.onboard=true", "track with the policy running in the vehicle's app"),
            ("checkpoint=<.pt>", "the policy (default: the preset's, src/datt/checkpoints/MANIFEST.md)"),
            ("traj=<option>", "the reference to fly (default: the star)"),
        ),
        (
            "python deploy.py",
            "python deploy.py deploy.onboard=true",
            "python deploy.py deploy=crazyflie deploy.uri=radio://0/80/2M/E7E7E7E7E7 deploy.mocap.source=motioncapture",
        ),
    ),
    "export": Usage(
        "Export a policy to C, a Crazyflie firmware app, TorchScript or ONNX.",
        (
            ("checkpoint=<.pt>", "the policy (default: what deploy.py flies onboard on the stock vehicle)"),
            ("format=c | app | torchscript | onnx", "what to write"),
            ("out_dir=<dir>", "where (default: the run dir)"),
            ("prefix=<name>", "C: file and function prefix"),
        ),
        ("datt export format=app", "datt export checkpoint=outputs/train/<run>/best.pt format=onnx"),
    ),
}


def config_groups_of(config_name: str) -> list[tuple[str, str]]:
    """The config groups the entry point's own config selects (its defaults list, ``hydra``
    excluded), each with its default option (``null``: none unless chosen)."""
    tree = OmegaConf.load(conf_dir() / f"{config_name}.yaml")
    out = []
    for entry in tree.get("defaults", []):
        if not isinstance(entry, (dict, type(tree))) or "_self_" in entry:
            continue
        for key, value in entry.items():
            group = str(key).removeprefix("optional ").removeprefix("override ").split("@")[0]
            if group != "hydra":
                out.append((group, "null" if value is None else str(value)))
    return out


def help_text(config_name: str, command: str) -> str:
    """The ``--help`` page of entry point ``config_name``, invoked as ``command``."""
    usage = USAGE[config_name]
    lines = [f"usage: {command} [override ...]   (Hydra overrides: key=value, group=option, -m for a sweep)", ""]
    lines += [usage.about, "", "most used:"]
    width = max(len(o) for o, _ in usage.overrides)
    lines += [f"  {o:{width}}  {what}" for o, what in usage.overrides]
    lines += ["", "examples:", *(f"  {e}" for e in usage.examples), "", "config groups (default first):"]
    groups = config_groups_of(config_name) + [(g, "null") for g in usage.extra_groups]
    for group, default in groups:
        options = [o for o in available_options(group, [conf_dir()]) if o != default]
        prefix = "+" if group in usage.extra_groups else ""
        lines.append(f"  {prefix}{group}: {default}" + (f" | {' | '.join(options)}" if options else ""))
    lines += [
        "",
        f"{command} --cfg job: the composed config;  {command} --hydra-help: Hydra's own flags;",
        "docs: README.md and docs/ (training.md, results.md, deploy.md, onboard.md)",
    ]
    return "\n".join(lines)
