"""Read what an offline wandb run recorded: its ``run-<id>.wandb`` file, wandb's LevelDB-style
log of protobuf ``Record`` messages (a 7-byte header ``:W&B`` + magic + version, then 32 KiB
blocks of chunks: crc32 (4), length (2, little-endian), type (1: full, 2: first, 3: middle,
4: last)). wandb 0.31 ships no Python reader for it, so the tests parse it with its protobuf."""

from __future__ import annotations

import json
import struct
from pathlib import Path

HEADER_LEN = 7
BLOCK_LEN = 32768
CHUNK_HEADER = 7
FULL, FIRST, MIDDLE, LAST = 1, 2, 3, 4


def records(path: Path):
    """Every Record of a ``.wandb`` file, in order."""
    from wandb.proto import wandb_internal_pb2

    data = Path(path).read_bytes()
    assert data[:4] == b":W&B", f"{path} is not a wandb run record"
    pos, pending = HEADER_LEN, b""
    while pos + CHUNK_HEADER <= len(data):
        left_in_block = BLOCK_LEN - pos % BLOCK_LEN
        if left_in_block < CHUNK_HEADER:  # the block's tail is padding
            pos += left_in_block
            continue
        _crc, length, kind = struct.unpack("<IHB", data[pos : pos + CHUNK_HEADER])
        chunk = data[pos + CHUNK_HEADER : pos + CHUNK_HEADER + length]
        pos += CHUNK_HEADER + length
        if kind == 0 and length == 0:
            continue
        pending = chunk if kind in (FULL, FIRST) else pending + chunk
        if kind in (FULL, LAST):
            rec = wandb_internal_pb2.Record()
            rec.ParseFromString(pending)
            yield rec
            pending = b""


def run_records(run_dir: Path, *kinds: str):
    """The Records of the given kinds (``run``, ``summary``, ``history``, ...) in every ``.wandb``
    file under ``run_dir/wandb``, in order (a resumed run appends a second file)."""
    for path in sorted(Path(run_dir).glob("wandb/*run-*/run-*.wandb")):
        for rec in records(path):
            if rec.WhichOneof("record_type") in kinds:
                yield rec


def _key(item) -> str:
    return item.key or "/".join(item.nested_key)


def summary_and_history(run_dir: Path) -> tuple[dict, set[str], list[str]]:
    """(the run's final summary, the keys ever logged to its history, its run ids) over every
    ``.wandb`` file under ``run_dir/wandb``."""
    summary: dict = {}
    history: set[str] = set()
    ids: list[str] = []
    for rec in run_records(run_dir, "run", "summary", "history"):
        kind = rec.WhichOneof("record_type")
        if kind == "run":
            ids.append(rec.run.run_id)
        elif kind == "summary":
            summary.update({_key(item): json.loads(item.value_json) for item in rec.summary.update})
        else:
            history.update(_key(item) for item in rec.history.item)
    return summary, history, ids


def run_info(run_dir: Path) -> list[dict]:
    """Each wandb run record under ``run_dir/wandb``: its id, group, job type, project, name, tags
    and config."""
    return [
        {
            "id": rec.run.run_id,
            "group": rec.run.run_group,
            "job_type": rec.run.job_type,
            "project": rec.run.project,
            "name": rec.run.display_name,
            "tags": list(rec.run.tags),
            "config": {item.key: json.loads(item.value_json) for item in rec.run.config.update},
        }
        for rec in run_records(run_dir, "run")
    ]


def history_rows(run_dir: Path) -> list[dict]:
    """Every history row (``_step`` and the logged values) of the runs under ``run_dir/wandb``."""
    rows = []
    for rec in run_records(run_dir, "history"):
        row = {_key(item): json.loads(item.value_json) for item in rec.history.item}
        if rec.history.HasField("step"):
            row.setdefault("_step", rec.history.step.num)
        rows.append(row)
    return rows


def metric_summaries(run_dir: Path) -> dict[str, str]:
    """Each ``define_metric`` of the runs under ``run_dir/wandb``: metric name -> the summary it
    keeps (min, max, mean, last ...)."""
    out = {}
    for rec in run_records(run_dir, "metric"):
        kept = [
            name for name in ("min", "max", "mean", "last", "best", "copy", "none") if getattr(rec.metric.summary, name)
        ]
        out[rec.metric.name or rec.metric.glob_name] = kept[0] if kept else ""
    return out


def artifacts(run_dir: Path) -> list[dict]:
    """Each artifact logged by the runs under ``run_dir/wandb``: name, type, aliases, the files
    of its manifest and its metadata."""
    return [
        {
            "name": rec.artifact.name,
            "type": rec.artifact.type,
            "aliases": list(rec.artifact.aliases),
            "files": [entry.path for entry in rec.artifact.manifest.contents],
            "metadata": json.loads(rec.artifact.metadata or "{}"),
        }
        for rec in run_records(run_dir, "artifact")
    ]


def _media(run_dir: Path, key: str) -> dict:
    """The last value logged under ``key`` (a wandb media object's JSON description)."""
    found = None
    for row in history_rows(run_dir):
        if key in row:
            found = row[key]
        elif f"{key}/_type" in row:
            found = {k.removeprefix(key + "/"): v for k, v in row.items() if k.startswith(key + "/")}
    assert found is not None, key
    return found


def image_captions(run_dir: Path) -> dict[str, str]:
    """The caption of each image logged by the runs under ``run_dir/wandb``, by its key."""
    out = {}
    for row in history_rows(run_dir):
        for key, value in row.items():
            if key.endswith("/_type") and value == "image-file":
                name = key.removesuffix("/_type")
                out[name] = row.get(f"{name}/caption", "")
    return out


def logged_table(run_dir: Path, key: str) -> dict:
    """The wandb Table logged under ``key``: its ``columns`` and ``data`` read from the table file
    the run stored beside its record."""
    media = _media(run_dir, key)
    path = media["path"]
    (file,) = [p for p in Path(run_dir).glob(f"wandb/*run-*/files/{path}")]
    return json.loads(file.read_text())
