"""Entry points: ``train.py`` / ``eval.py`` (root shims) and the ``datt`` console script.

Every user error ends in one line on stderr (``error: <key>: <what>``) and exit code 2.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Callable

from omegaconf import DictConfig, OmegaConf
from rich.console import Console
from rich.table import Table

from datt.config import CONF_DIR, SWEEPS_DIR, ConfigError, available_options

console = Console()


# -- shared helpers ------------------------------------------------------------------------
def _run_dir() -> Path:
    from hydra.core.hydra_config import HydraConfig

    return Path(HydraConfig.get().runtime.output_dir)


def _original_cwd() -> Path:
    try:
        from hydra.utils import get_original_cwd

        return Path(get_original_cwd())
    except ValueError:
        return Path.cwd()


def resolve_path(path: str | Path) -> Path:
    """A user path: absolute, else relative to where the command ran, else to the repository
    (so the shipped ``checkpoints/...`` work from any directory)."""
    p = Path(str(path)).expanduser()
    if p.is_absolute():
        return p
    here = _original_cwd() / p
    repo = CONF_DIR.parent / p
    return here if here.exists() or not repo.exists() else repo


def _set_threads(n) -> None:
    """``n`` torch threads; ``None`` = automatic: under the joblib launcher, the cores divided by
    the parallel jobs (so 2 jobs on 2 cores use 1 thread each instead of oversubscribing)."""
    n = n or joblib_threads()
    if n:
        import torch

        torch.set_num_threads(int(n))


def joblib_threads() -> int | None:
    import os

    try:
        from hydra.core.hydra_config import HydraConfig

        launcher = HydraConfig.get().launcher
    except (ImportError, ValueError):
        return None
    if "joblib" not in str(launcher.get("_target_", "")):
        return None
    cores = os.cpu_count() or 1
    n_jobs = int(launcher.get("n_jobs") or -1)
    n_jobs = cores + 1 + n_jobs if n_jobs < 0 else n_jobs  # joblib: -1 = all cores, -2 = all but one
    return max(1, cores // max(1, min(n_jobs, cores)))


def preflight(argv: list[str]) -> None:
    """Reject unknown config-group options before Hydra prints a multi-line error."""
    groups = {p.name for p in CONF_DIR.iterdir() if p.is_dir()} | {"sweep"}
    for arg in argv:
        if arg.startswith("-") or "=" not in arg:
            continue
        key, value = arg.split("=", 1)
        key = key.lstrip("+~")
        group = key.split("@")[0]
        if group in groups and "," not in value and "(" not in value:
            allowed = available_options(group)
            if value not in allowed and value != "null":
                raise ConfigError(f"{group}: unknown option {value!r}; allowed: {', '.join(allowed)}")


def hydra_main(config_name: str, task: Callable[[DictConfig], object]) -> Callable[[], None]:
    """Wrap ``task`` in ``@hydra.main`` with one-line error reporting."""
    import hydra

    from datt.config import TrainingDiverged

    @hydra.main(config_path=str(CONF_DIR), config_name=config_name, version_base="1.3")
    def _main(cfg: DictConfig) -> None:
        try:
            task(cfg)
        except ConfigError as exc:
            print(f"error: {exc}", file=sys.stderr)
            sys.exit(2)
        except TrainingDiverged as exc:
            print(f"error: training diverged: {exc}", file=sys.stderr)
            sys.exit(3)

    def entry() -> None:
        try:
            preflight(sys.argv[1:])
        except ConfigError as exc:
            print(f"error: {exc}", file=sys.stderr)
            sys.exit(2)
        if not any(a.startswith("hydra.searchpath") for a in sys.argv[1:]):
            # sweeps/ is found from any working directory (absolute path from the package location)
            # (next to the other overrides: argparse wants Hydra's positional overrides contiguous)
            at = next((i for i, a in enumerate(sys.argv) if i and "=" in a and not a.startswith("-")), len(sys.argv))
            sys.argv.insert(at, f"hydra.searchpath=[file://{SWEEPS_DIR}]")
        _main()

    return entry


def print_metrics(title: str, conditions: dict) -> None:
    from datt.eval.metrics import format_error

    table = Table(title=title)
    table.add_column("condition")
    groups = list(next(iter(conditions.values()))["groups"])
    for g in groups:
        table.add_column(f"{g} error (m)", justify="right")
    for cond, res in conditions.items():
        table.add_row(cond, *(format_error(res["groups"][g]) for g in groups))
    console.print(table)


def evaluate_conditions(cfg: DictConfig, policy, conditions: dict, run_dir: Path, plots: bool, tag: str,
                        trace_path: Path | None = None) -> dict:  # fmt: skip
    """Fly the bank under each condition with ``policy``: a trained actor, a ready
    :class:`~datt.control.Controller`, or None (hovering, the reference point)."""
    from datt.control import Controller, DattController, HoverController
    from datt.eval.plots import plot_group_axes, plot_tracks
    from datt.eval.rollout import evaluate

    results = {}
    eval_cfg = OmegaConf.merge(cfg, {"env": {"compile": False}})
    if policy is None:
        factory = lambda env: HoverController()  # noqa: E731
    elif isinstance(policy, Controller):
        factory = lambda env: policy  # noqa: E731
    else:
        factory = lambda env: DattController(policy)  # noqa: E731
    for name, cond in conditions.items():
        if cond is None:  # a sweep can drop a default condition by setting it to null
            continue
        res = evaluate(eval_cfg, factory, cond["disturbance"], cond["adaptation"], seed=int(cfg.eval.get("seed", 0)))
        labels = {k: v if isinstance(v, str) else OmegaConf.to_container(v) for k, v in cond.items()}
        if trace_path is not None:  # for side-by-side plots across controllers (tables.py main)
            import torch

            tr = res["trace"]
            torch.save({"pos_m": tr.pos_m, "ref_m": tr.ref_m, "err_m": tr.err_m, "crashed_at": tr.crashed_at,
                        "names": res["names"], "counts": res["counts"]}, trace_path)  # fmt: skip
        results[name] = {**labels, "groups": res["groups"]}
        if plots:
            slug = "".join(c if c.isalnum() else "_" for c in name)
            plot_tracks(res["trace"], res["names"], res["counts"], run_dir / f"tracks_{slug}.png", title=f"{tag}: {name}")
            plot_group_axes(res["trace"], res["names"], res["counts"], float(cfg.env.dt_s), run_dir / f"axes_{slug}.png",
                            title=f"{tag}: {name}")  # fmt: skip
    return results


# -- train ---------------------------------------------------------------------------------
def _resume_dir(resume) -> Path | None:
    if resume in (False, None, "false", "False"):
        return None
    if resume in (True, "true", "True"):
        candidates = sorted((_original_cwd() / "outputs").glob("**/last.pt"), key=lambda p: p.stat().st_mtime)
        if not candidates:
            raise ConfigError("resume: no run with a last.pt under outputs/; pass resume=<run dir>")
        return candidates[-1].parent
    path = resolve_path(resume)
    if not (path / "last.pt").is_file():
        raise ConfigError(f"resume: {str(path)!r} has no last.pt")
    return path


def wandb_group_and_tags(cfg: DictConfig, run_dir: Path) -> tuple[str | None, list[str]]:
    """All jobs of one multirun share a wandb group (``<sweep_name or multirun>/<sweep dir>``) and are
    tagged with their swept overrides (``ablation=h5``, ``seed=1``), so dashboards group by them."""
    group, tags = cfg.logger.get("group"), [str(t) for t in (cfg.logger.get("tags") or [])]
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        hc = HydraConfig.get()
    except (ImportError, ValueError):
        return group, tags
    if hc.mode == RunMode.MULTIRUN:
        group = f"{cfg.get('sweep_name') or 'multirun'}/{run_dir.parent.name}"
        tags += [o.lstrip("+") for o in hc.overrides.task if not o.lstrip("+").startswith(("sweep=", "hydra"))]
    return group, [t[:64] for t in tags]  # wandb caps tag length at 64


def run_train(cfg: DictConfig, run_dir: Path | None = None) -> dict:
    """Train, checkpoint, evaluate; returns the metrics written to ``metrics.json``."""
    from datt.eval.plots import plot_learning_curve
    from datt.train.logging import CsvLogger, MultiLogger, WandbLogger
    from datt.train.ppo import Trainer, TrainingDiverged

    _set_threads(cfg.train.get("threads"))
    if cfg.get("stage", "ppo") == "rma":
        return run_rma(cfg, run_dir or _run_dir())
    if cfg.get("stage", "ppo") != "ppo":
        raise ConfigError(f"stage: unknown value {cfg.stage!r}; allowed: ppo, rma")
    resume_dir = _resume_dir(cfg.get("resume", False))
    run_dir = resume_dir or run_dir or _run_dir()
    run_dir.mkdir(parents=True, exist_ok=True)
    if resume_dir is None:
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    loggers = [CsvLogger(run_dir)]
    if cfg.logger.get("wandb", False):
        group, tags = wandb_group_and_tags(cfg, run_dir)
        loggers.append(
            WandbLogger(run_dir, OmegaConf.to_container(cfg, resolve=True), project=cfg.logger.project, group=group,
                        tags=tags, mode=cfg.logger.mode, name=run_dir.name, run_id=f"{run_dir.parent.name}-{run_dir.name}")  # fmt: skip
        )
    logger = MultiLogger(loggers)
    trainer = Trainer(cfg, run_dir, logger, console)
    if resume_dir is not None:
        trainer.load(resume_dir / "last.pt")
        console.print(f"resuming {resume_dir} at {trainer.frames:,} frames")
    console.print(f"run dir: {run_dir}")
    t0 = time.perf_counter()
    try:
        history = trainer.train()
    except TrainingDiverged as exc:
        # tables.py reports this run as "failed" (as the paper does for diverged ablations)
        (run_dir / "failed.json").write_text(json.dumps({"message": str(exc), "frames": trainer.frames}) + "\n")
        raise
    finally:
        logger.close()
    wall_s = time.perf_counter() - t0
    metrics = {
        "frames": trainer.frames,
        "train_wall_s": wall_s,
        "steps_per_s": (trainer.frames / wall_s) if history else None,
        "horizon": trainer.env.horizon,
        "seed": int(cfg.seed),
    }
    if history and cfg.eval.get("plots", True):
        plot_learning_curve(trainer.history, run_dir / "learning_curve.png")
    if cfg.train.eval_at_end:
        metrics["conditions"] = evaluate_conditions(cfg, trainer.actor, cfg.eval.conditions, run_dir,
                                                    cfg.eval.get("plots", True), tag=run_dir.name)  # fmt: skip
        clean = {"disturbance": "none", "adaptation": "none"}
        metrics["hover_reference"] = evaluate_conditions(cfg, None, {"hover": clean}, run_dir, False, "hover")["hover"]
        print_metrics(f"evaluation ({run_dir.name})", {**metrics["conditions"], "hover (reference)": metrics["hover_reference"]})
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    return metrics


def run_rma(cfg: DictConfig, run_dir: Path) -> dict:
    """Fit an RMA adapter for ``base_checkpoint`` and evaluate DATT-RMA vs privileged/L1/none."""
    from datt.adapt.rma import train_rma
    from datt.control.datt import DattController
    from datt.eval.rollout import evaluate

    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    result = train_rma(cfg, run_dir, console)
    actor, train_cfg, _ = load_actor(cfg.base_checkpoint)
    eval_cfg = OmegaConf.merge(train_cfg, {"eval": cfg.eval, "env": {"compile": False}})
    conditions = {}
    for name, adaptation in (("d_hat=0", "none"), ("l1", "l1"), ("rma", None), ("privileged", "privileged")):
        choice = adaptation if adaptation else {"_target_": "datt.adapt.RmaAdaptation", "checkpoint": str(run_dir / "rma.pt")}
        res = evaluate(eval_cfg, lambda env: DattController(actor), "brownian", choice, seed=int(cfg.eval.get("seed", 0)))
        conditions[name] = {"disturbance": "brownian", "adaptation": name, "groups": res["groups"]}
    print_metrics("DATT under Brownian disturbance by adaptation", conditions)
    metrics = {"rma_train_wall_s": result["wall_s"], "rma_history": result["history"], "conditions": conditions}
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    return metrics


# -- eval ----------------------------------------------------------------------------------
def load_actor(path: str | Path):
    """Actor and its training config from a checkpoint (file or run dir)."""
    from datt.config import env_params_from_cfg, structured
    from datt.envs.tracking import action_bounds
    from datt.envs.observations import state_width
    from datt.policies.networks import PolicyParams, make_actor
    from datt.train.checkpoint import load_checkpoint

    data = load_checkpoint(resolve_path(path))
    train_cfg = OmegaConf.create(data["config_yaml"])
    params = structured(PolicyParams, train_cfg.policy, "policy")
    env_params = env_params_from_cfg(train_cfg.env)
    low, high = action_bounds(env_params)
    actor = make_actor(int(data["horizon"]), low, high, params, state_width(env_params.obs))
    actor.load_state_dict(data["actor"])
    actor.eval()
    return actor, train_cfg, data


def _choice(group: str, default: str = "custom") -> str:
    """The option name Hydra chose for ``group`` (for labels)."""
    try:
        from hydra.core.hydra_config import HydraConfig

        return str(HydraConfig.get().runtime.choices.get(group, default))
    except ValueError:
        return default


def build_controller(cfg: DictConfig):
    """The controller ``cfg.controller`` names, the config to evaluate it under, and labels.

    Options without ``_target_`` (datt, datt_l1, datt_rma) load the policy from ``checkpoint``; its
    observation layout (horizon, ablations) comes from its training config. An ``adaptation`` key
    in the controller option fixes the estimator it flies with (l1_pid, l1_mppi, datt_l1, ...).
    """
    from datt.config import instantiate_option, with_options
    from datt.control import DattController

    node = OmegaConf.to_container(cfg.controller, resolve=True)
    name, forced = str(node.pop("name")), node.pop("adaptation", None)
    # a resolved, non-struct copy, with the controller's own estimator if it fixes one
    merged = with_options(cfg, **({"adaptation": str(forced)} if forced else {}))
    labels = {"controller": name, "disturbance": _choice("disturbance"), "adaptation": forced or _choice("adaptation")}
    if "_target_" in node:
        return instantiate_option(OmegaConf.create({"controller": node}), "controller"), merged, labels
    actor, train_cfg, data = load_actor(cfg.checkpoint)
    merged = OmegaConf.merge(merged, {"horizon": train_cfg.horizon, "env": {"obs": train_cfg.env.obs}})
    OmegaConf.set_struct(merged, False)
    return DattController(actor, frozen=True), merged, {**labels, "checkpoint": str(cfg.checkpoint), "frames": int(data["frames"])}


def measure_inference(cfg: DictConfig, controller) -> dict | None:
    """Median/p95 ms per control step at batch 1 (see :mod:`datt.eval.timing`)."""
    from datt.config import make_env
    from datt.eval.timing import step_times_ms, summarize_ms

    timing = cfg.eval.get("timing") or {}
    if int(timing.get("steps", 0)) <= 0:
        return None
    env = make_env(cfg, num_envs=1, seed=int(cfg.seed))
    if timing.get("compile", True):
        env.compile_kernels(sim=False)  # the controller side: observation kernel and adaptation update
    threads = int(timing.get("threads", 1))
    times = step_times_ms(env, controller, int(timing.steps), int(timing.get("warmup_steps", 20)), threads=threads)
    return {**summarize_ms(times), "batch": 1, "threads": threads}


def write_metrics_csv(path: Path, conditions: dict) -> None:
    import csv

    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["condition", "group", "mean_m", "std_m", "crashes", "episodes"])
        for cond, res in conditions.items():
            for group, row in res["groups"].items():
                w.writerow([cond, group, row["mean_m"], row["std_m"], row["crashes"], row["episodes"]])


def run_eval(cfg: DictConfig, run_dir: Path | None = None) -> dict:
    """``eval.py``: one controller over the seeded bank, per seed (``eval.seeds``), plus its
    per-step inference time at batch 1."""
    run_dir = run_dir or _run_dir()
    run_dir.mkdir(parents=True, exist_ok=True)
    _set_threads(cfg.get("threads"))
    controller, merged, labels = build_controller(cfg)
    name = labels["controller"]
    cond = {"disturbance": merged.disturbance, "adaptation": merged.adaptation}
    label = f"{name} {labels['disturbance']}/{labels['adaptation']}"
    results = {}
    for seed in cfg.eval.seeds:
        merged.eval.seed = int(seed)
        results.update(evaluate_conditions(merged, controller, {f"{label} seed {seed}": cond}, run_dir, cfg.eval.plots, name,
                                           trace_path=run_dir / f"trace_seed{seed}.pt" if cfg.eval.get("save_trace") else None))
    metrics = {**labels, "conditions": results}
    print_metrics(f"{name} on the seeded bank", results)
    inference = measure_inference(merged, controller)
    if inference is not None:
        metrics["inference_ms"] = inference
        console.print(f"inference at batch 1: median {inference['median_ms']:.3f} ms, p95 {inference['p95_ms']:.3f} ms "
                      f"({inference['steps']} steps after warm-up, {inference['threads']} threads)")  # fmt: skip
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2, default=str) + "\n")
    write_metrics_csv(run_dir / "metrics.csv", results)
    return metrics


# -- tables --------------------------------------------------------------------------------
def run_tables(cfg: DictConfig, run_dir: Path | None = None) -> dict:
    """``tables.py <table>``: (optionally run the sweep, then) collect its jobs into the table."""
    import subprocess

    from datt.eval import tables as T

    spec = T.get_spec(str(cfg.table))
    outputs = _original_cwd() / "outputs"
    if cfg.get("run", False):
        sweep_dir = outputs / "sweeps" / spec.name / time.strftime("%Y-%m-%d_%H-%M-%S")
        cmd = [sys.executable, str(CONF_DIR.parent / spec.entry), "-m", f"+sweep={spec.name}",
               *[str(o) for o in cfg.get("sweep_overrides") or []], f"hydra.sweep.dir={sweep_dir}"]  # fmt: skip
        console.print("running: " + " ".join(cmd[1:]))
        if subprocess.run(cmd, cwd=_original_cwd()).returncode != 0:
            raise ConfigError(f"run: the {spec.name} sweep failed (see its output above); finished jobs are in {sweep_dir}")
        roots = [sweep_dir]
    elif cfg.get("runs"):
        runs = cfg.runs if isinstance(cfg.runs, (list, tuple)) or OmegaConf.is_list(cfg.runs) else [cfg.runs]
        roots = [resolve_path(r) for r in runs]
        for r in roots:
            if not r.exists():
                raise ConfigError(f"runs: {str(r)!r} does not exist")
    else:
        roots = T.default_roots(spec, outputs)
    jobs = T.find_jobs(roots)
    if not jobs:
        raise ConfigError(f"runs: no Hydra job dirs under {', '.join(map(str, roots))}")
    rows, _ = T.collect(spec, jobs)
    rendered = T.render(spec, rows, jobs)
    out_dir = resolve_path(cfg.out_dir) if cfg.get("out_dir") else roots[0]
    files = T.write(spec, rendered, out_dir)
    if cfg.get("plots", True) and spec.kind == "train":
        files += T.plot_train_sweep(spec, rows, jobs, out_dir)
    if cfg.get("plots", True) and spec.kind == "eval":
        sbs = cfg.get("side_by_side") or {}
        path = T.plot_side_by_side_from_jobs(jobs, str(sbs.get("group", "zigzag")), int(sbs.get("index", 0)), out_dir / f"{spec.name}_side_by_side.png")
        files += [path] if path else []
    table = Table(title=spec.title)
    for h in rendered["header"]:
        table.add_column(h)
    for r in rendered["rows"]:
        table.add_row(*r)
    console.print(table)
    for note in T._job_notes(jobs):
        console.print(note)
    console.print("wrote " + ", ".join(str(f) for f in files))
    return {"files": [str(f) for f in files], "rows": rendered["rows"], "jobs": len(jobs)}


def _tables_entry(inner: Callable[[], None]) -> Callable[[], None]:
    """``tables.py ablation`` = ``tables.py table=ablation`` (a positional table name)."""

    def entry() -> None:
        if len(sys.argv) > 1 and "=" not in sys.argv[1] and not sys.argv[1].startswith("-"):
            sys.argv[1] = f"table={sys.argv[1]}"
        inner()

    return entry


# -- deploy --------------------------------------------------------------------------------
def run_deploy(cfg: DictConfig, run_dir: Path | None = None, estop=None, server_hook=None) -> dict:
    """``deploy.py``: takeoff -> track -> land through cflib, against the simulated Crazyflie
    (``deploy=sim``, started here) or a real one (``deploy=crazyflie``). ``server_hook(server,
    runner)`` lets tests inject faults once the flight objects exist."""
    from urllib.parse import urlparse

    from datt.config import instantiate_option, make_env, structured, with_options
    from datt.control.pid import PidController
    from datt.deploy import mocap as M
    from datt.deploy.link import CrazyflieLink, LinkError
    from datt.deploy.runner import FlightParams, FlightRunner
    from datt.deploy.safety import SafetyParams
    from datt.deploy.thrust import ThrustMap, ThrustParams

    run_dir = run_dir or _run_dir()
    run_dir.mkdir(parents=True, exist_ok=True)
    _set_threads(cfg.get("threads"))
    d = cfg.deploy
    controller, merged, labels = build_controller(cfg)
    model_cfg = with_options(merged, disturbance="none")
    model_cfg.env.init_pos_range_m = 0.0
    model_cfg.env.compile = False

    def make_flight_env(family):
        return make_env(model_cfg, num_envs=1, seed=int(cfg.seed), traj=family)

    thrust_params = structured(ThrustParams, d.thrust, "deploy.thrust")
    server = None
    if d.get("server") is not None:
        from datt.deploy.sim import SimCrazyflie, SimCrazyflieParams

        url = urlparse(str(d.uri))
        if url.scheme != "udp":
            raise ConfigError(f"deploy.uri: the simulated Crazyflie listens on udp://host:port, got {d.uri!r}")
        server_cfg = {k: (tuple(v) if OmegaConf.is_list(v) else v) for k, v in d.server.items()}
        # the simulated vehicle's motors follow the model at its true mass (never the user's calibration)
        true_mass = server_cfg.pop("mass_kg", None) or thrust_params.mass_kg
        vehicle = ThrustParams(mass_kg=float(true_mass), k2=thrust_params.k2, k1=thrust_params.k1, k0=thrust_params.k0)
        sp = SimCrazyflieParams(host=url.hostname, port=url.port, thrust=vehicle, **server_cfg)
        server = SimCrazyflie(sp, disturbance=instantiate_option(cfg, "disturbance")).start()
    source = str(d.mocap.get("source", "none"))
    if source == "none":
        mocap = M.NoMocap()
    elif source == "simulated":
        if server is None:
            raise ConfigError("deploy.mocap.source: 'simulated' needs the simulated Crazyflie (deploy=sim)")
        mocap = M.SimulatedMocap(server, latency_s=float(d.mocap.latency_s), dropout_prob=float(d.mocap.dropout_prob),
                                 dropout_after_s=d.mocap.get("dropout_after_s"))  # fmt: skip
    elif source == "motioncapture":
        mocap = M.MotionCaptureMocap(str(d.mocap.system), str(d.mocap.host), str(d.mocap.body))
    else:
        raise ConfigError(f"deploy.mocap.source: unknown source {source!r}; allowed: none, simulated, motioncapture")
    link = CrazyflieLink(str(d.uri), int(d.log_period_ms), float(d.connect_timeout_s), float(d.io_timeout_s))
    track_family = instantiate_option(cfg, "traj")
    runner = FlightRunner(link, mocap, make_flight_env, controller, PidController, track_family,
                          structured(FlightParams, d.flight, "deploy.flight"), structured(SafetyParams, d.safety, "deploy.safety"),
                          ThrustMap(thrust_params), run_dir, estop=estop, console=console)  # fmt: skip
    if server_hook is not None:
        server_hook(server, runner)
    mode = str(d.get("mode", "fly"))
    if mode not in ("fly", "calibrate"):
        raise ConfigError(f"deploy.mode: unknown mode {mode!r}; allowed: fly, calibrate")
    try:
        summary = runner.fly() if mode == "fly" else runner.calibrate(float(d.get("calibrate_hover_s", 4.0)))
    except LinkError as exc:
        raise ConfigError(str(exc)) from None
    finally:
        if server is not None:
            server.stop()
    summary["controller"] = labels
    (run_dir / "events.json").write_text(json.dumps(summary, indent=2, default=str) + "\n")
    if mode == "calibrate":
        console.print(f"calibration: {summary['outcome']}; hover command {summary['hover_command']} "
                      f"(set deploy.thrust.hover_command)")  # fmt: skip
    err = summary["track_error_m"]
    console.print(f"flight: {summary['outcome']}; tracking error {err if err is None else f'{err:.3f} m'} over "
                  f"{summary['track_steps']} steps; tick jitter median {summary['jitter_ms']['median']:.2f} ms, "
                  f"p99 {summary['jitter_ms']['p99']:.2f} ms; {summary['late_ticks']} late ticks; log in {run_dir}")  # fmt: skip
    return summary


# -- console script ------------------------------------------------------------------------
train_main = hydra_main("train", run_train)
eval_main = hydra_main("eval", run_eval)
tables_main = _tables_entry(hydra_main("tables", run_tables))
deploy_main = hydra_main("deploy", run_deploy)
COMMANDS = {"train": train_main, "eval": eval_main, "tables": tables_main, "deploy": deploy_main}


def main() -> None:
    """``datt <command> [hydra overrides]``."""
    if len(sys.argv) < 2 or sys.argv[1] not in COMMANDS:
        print(f"usage: datt {{{','.join(COMMANDS)}}} [overrides...]", file=sys.stderr)
        sys.exit(2)
    command = sys.argv.pop(1)
    sys.argv[0] = f"datt {command}"
    COMMANDS[command]()


__all__ = ["main", "run_train", "run_eval", "load_actor"]
