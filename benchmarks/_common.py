"""Shared helpers for benchmark scripts: machine description and result files."""

from __future__ import annotations

import os
import platform
import time
from pathlib import Path

import torch

from datt.runs import write_json

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def machine_info() -> dict:
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "platform": platform.platform(),
    }


def write_result(name: str, payload: dict) -> Path:
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    path = RESULTS_DIR / f"{name}.json"
    payload = {"benchmark": name, "date": time.strftime("%Y-%m-%dT%H:%M:%S"), "machine": machine_info(), **payload}
    return write_json(path, payload)  # strict JSON (NaN -> null), written atomically


def timed_training_config(description: str, default_iterations: int, *extra: str):
    """The command line of a script that times ``--iterations`` PPO iterations of the training
    config (``overrides`` on top): returns (the config as given, the config to run, its overrides,
    frames per iteration). The run is quiet (no progress lines, csv logger, no mid-run checkpoints)
    and gets ``extra`` overrides too."""
    import argparse

    from datt.configuration import compose

    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--iterations", type=int, default=default_iterations)
    parser.add_argument("overrides", nargs="*", default=[])
    args = parser.parse_args()
    probe = compose("train", args.overrides)
    per_iter = probe.algo.num_envs * probe.algo.rollout_steps
    overrides = [
        *args.overrides,
        f"train.total_frames={per_iter * args.iterations}",
        "train.progress=false",
        "train.checkpoint_every=1000000",
        "logger=csv",
        *extra,
    ]
    return probe, compose("train", overrides), overrides, per_iter
