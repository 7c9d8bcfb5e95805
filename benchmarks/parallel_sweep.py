"""Parallel local sweeps with the joblib launcher: wall time of 2 jobs vs 1 job.

    python benchmarks/parallel_sweep.py [--steps 400000]

Runs one short training job alone (basic launcher, all cores), then the same job twice at once
through ``hydra/launcher=joblib`` (each job gets cores / 2 torch threads automatically). Two jobs
use both cores well if their wall time is < 1.5x the single job's. Writes
``benchmarks/results/parallel_sweep.json``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import write_result

REPO = Path(__file__).resolve().parents[1]


def timed(args: list[str], cwd: str) -> float:
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, str(REPO / "train.py"), *args], cwd=cwd, capture_output=True, text=True)
    if out.returncode:
        raise SystemExit(out.stderr[-3000:])
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=400_000)
    a = ap.parse_args()
    common = [
        f"train.total_frames={a.steps}",
        "curriculum.fixed_ref_frames=0",
        "logger=csv",
        "train.progress=false",
        "eval.plots=false",
        "eval.conditions.brownian=null",
        "env.compile=false",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        one = timed(["-m", "seed=0", *common], tmp)
        two = timed(["-m", "seed=0,1", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", *common], tmp)
    ratio = two / one
    print(f"1 job: {one:.1f} s   2 jobs with joblib (n_jobs=2): {two:.1f} s   ratio {ratio:.2f} (target < 1.5)")
    path = write_result(
        "parallel_sweep", {"steps_per_job": a.steps, "one_job_s": one, "two_jobs_joblib_s": two, "ratio": ratio}
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
