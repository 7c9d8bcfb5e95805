"""The paper's simulated figures, regenerated: the appendix's tracking of a zigzag and a chained
polynomial, and the L1's disturbance estimate d̂ against the disturbance d.

    python tools/paper_figures.py [checkpoint=...] [eval.py overrides...]

Flies ``python eval.py controller=datt_l1 disturbance=brownian bank@eval.bank=paper_figure``
(the shipped policy with the L1 under the paper's Brownian disturbance, on the first zigzag and
the first chained polynomial of the default bank; ``conf/bank/paper_figure.yaml``) in a temporary
run dir and keeps its figures as ``docs/results/figures/tracking_zigzag_chained_poly.png`` (x, y,
z against time, reference dashed) and ``docs/results/figures/dhat_l1_brownian.png`` (d dashed, d̂
solid, per axis), with the run's errors in ``docs/results/figures/figures.json``.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from datt.cli import run_tool
from datt.errors import ConfigError
from datt.runs import write_json

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "results" / "figures"
COMMAND = ["controller=datt_l1", "disturbance=brownian", "bank@eval.bank=paper_figure"]


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        overrides = [*COMMAND, *sys.argv[1:], f"hydra.run.dir={run}"]
        proc = subprocess.run([sys.executable, str(ROOT / "eval.py"), *overrides], cwd=ROOT)
        if proc.returncode != 0:
            raise ConfigError(f"paper_figures: eval.py {' '.join(overrides)} exited {proc.returncode}")
        (axes,), (dhat,) = run.glob("axes_*.png"), run.glob("dhat_*.png")
        OUT.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(axes, OUT / "tracking_zigzag_chained_poly.png")
        shutil.copyfile(dhat, OUT / "dhat_l1_brownian.png")
        metrics = json.loads((run / "metrics.json").read_text())
        record = {
            "command": "python eval.py " + " ".join(overrides[:-1]),
            "checkpoint": metrics.get("checkpoint"),
            "errors_m": {
                name: {group: row["mean_m"] for group, row in cond["groups"].items()}
                for name, cond in metrics["conditions"].items()
            },
        }
        write_json(OUT / "figures.json", record)
    print(f"wrote {OUT / 'tracking_zigzag_chained_poly.png'}, {OUT / 'dhat_l1_brownian.png'}, {OUT / 'figures.json'}")


if __name__ == "__main__":
    run_tool(main)
