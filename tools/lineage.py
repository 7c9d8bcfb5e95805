"""Print how a checkpoint was trained: the chain of runs its weights descend from.

    python tools/lineage.py outputs/train/<run>/last.pt

Every checkpoint records the checkpoints it was fine-tuned from (``train.init_from``, and the
earlier stages of a ``train.stages`` schedule) with their whole configs (``lineage``, see
``datt.checkpoint``). This prints one step per run, oldest first: the frames it trained and the
config values it changed from the step before (the first step: its seed and the values it sets
away from today's ``python train.py`` defaults). A checkpoint written before lineage was recorded
has none, and says so.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from omegaconf import OmegaConf

from datt.checkpoint import load_checkpoint
from datt.configuration import compose, flat_leaves

# keys that name where a run came from or how it was carried on, not what it trained
IGNORED = (
    "train.init_from",
    "train.stages",
    "train.progress",
    "train.checkpoint_every",
    "train.threads",  # its spelling before it moved to the top level
    "threads",
    "logger.",
    "eval.",
)


def config_changes(before: dict[str, object], after: dict[str, object]) -> list[str]:
    """``key: old -> new`` for every training value that differs (added or removed keys too)."""
    lines = []
    for key in sorted(before.keys() | after.keys()):
        if key.startswith(IGNORED):
            continue
        old, new = before.get(key, "(absent)"), after.get(key, "(absent)")
        if old != new:
            lines.append(f"{key}: {old} -> {new}")
    return lines


def steps(path: Path) -> list[tuple[str, int, dict[str, object]]]:
    """(where, frames, flat resolved config) for each run of the chain, oldest first."""
    data = load_checkpoint(path)
    chain = [
        *data.get("lineage", []),
        {"checkpoint": str(path), "frames": data["frames"], "config_yaml": data["config_yaml"]},
    ]
    return [
        (
            str(entry["checkpoint"]),
            int(entry["frames"]),
            flat_leaves(OmegaConf.to_container(OmegaConf.create(entry["config_yaml"]), resolve=True)),
        )
        for entry in chain
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", type=Path)
    args = parser.parse_args()
    chain = steps(args.checkpoint)
    if len(chain) == 1 and chain[0][2].get("train.init_from"):
        print(f"{args.checkpoint}: fine-tuned from {chain[0][2]['train.init_from']}, whose config it did not record")
    previous = flat_leaves(OmegaConf.to_container(compose("train"), resolve=True))
    total = 0
    for k, (where, frames, cfg) in enumerate(chain, start=1):
        total += frames
        print(f"{k}. {where}: {frames:,} frames (chain total {total:,}), seed {cfg.get('seed')}")
        for line in config_changes(previous, cfg) or ["(no change)"]:
            print(f"     {line}")
        previous = cfg


if __name__ == "__main__":
    main()
