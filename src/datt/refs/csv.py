"""User references from a CSV file with a header row and columns ``t,x,y,z`` (s, m, world)."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import torch
from torch import Tensor

from datt.configuration import Range, check_arg_ranges
from datt.errors import ConfigError
from datt.refs.base import RefFamily, piecewise_linear

REQUIRED_COLUMNS = ("t", "x", "y", "z")


def _resolve(path: str | Path) -> Path:
    """Relative paths mean relative to where the user ran the command (Hydra's original working
    directory inside a job, else the working directory)."""
    from hydra.utils import to_absolute_path

    return Path(to_absolute_path(str(Path(path).expanduser())))


def load_csv_reference(path: str | Path, key: str = "traj.path") -> tuple[Tensor, Tensor]:
    """Read and validate a reference file -> times ``[M]`` (float64, from 0) and positions ``[M, 3]``.

    Raises ``ConfigError`` (one line, naming ``key``) for a missing file, missing columns,
    non-numeric or NaN/inf values, fewer than two rows, or times that do not strictly increase.
    """
    p = _resolve(path)
    if not p.is_file():
        raise ConfigError(f"{key}: file {str(p)!r} not found")
    try:  # the whole file at once: a bad byte anywhere is this one line, not a traceback mid-parse
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{key}: {p.name} is not UTF-8 text (byte {exc.start}); save it as UTF-8 CSV") from None
    # Spreadsheets in many locales write ';' (decimal comma) or tabs; a BOM is dropped by utf-8-sig.
    first = text.split("\n", 1)[0]
    delimiter = next((d for d in (",", ";", "\t") if d in first), ",")
    reader = csv.DictReader(io.StringIO(text, newline=""), delimiter=delimiter)
    header = [h.strip() for h in (reader.fieldnames or [])]
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        raise ConfigError(
            f"{key}: {p.name} is missing column(s) {', '.join(missing)}; required: {', '.join(REQUIRED_COLUMNS)} "
            f"(header read as {header} with separator {delimiter!r})"
        )
    rows = []
    for line_no, row in enumerate(reader, start=2):
        row = {k.strip(): v for k, v in row.items() if k is not None}
        try:
            rows.append([float(row[c]) for c in REQUIRED_COLUMNS])
        except (TypeError, ValueError):
            hint = " (decimal commas? use '.' for decimals)" if delimiter == ";" else ""
            raise ConfigError(f"{key}: {p.name} line {line_no}: non-numeric value in t,x,y,z{hint}") from None
    if len(rows) < 2:
        raise ConfigError(f"{key}: {p.name} needs at least 2 data rows, got {len(rows)}")
    data = torch.tensor(rows, dtype=torch.float64)
    bad = ~torch.isfinite(data).all(dim=1)
    if bad.any():
        raise ConfigError(f"{key}: {p.name} line {int(bad.nonzero()[0]) + 2}: NaN or inf value")
    t = data[:, 0]
    dec = (t[1:] <= t[:-1]).nonzero()
    if len(dec):
        i = int(dec[0])
        raise ConfigError(
            f"{key}: {p.name} line {i + 3}: time must strictly increase (t={t[i + 1].item()} after {t[i].item()})"
        )
    return t - t[0], data[:, 1:]


def check_extent(pos_m: Tensor, max_abs_m: float, name: str, key: str = "traj.max_abs_m") -> None:
    """Refuse positions beyond ``max_abs_m`` (a unit mistake such as mm for m, or a far-away frame)."""
    worst = pos_m.abs().max().item()
    if worst > max_abs_m:
        row = int(pos_m.abs().amax(dim=1).argmax()) + 2
        raise ConfigError(
            f"{key}: {name} line {row} is {worst:.4g} m from the origin, beyond {max_abs_m:g} m (positions are "
            "metres; use relative=true for a far-away frame, or raise traj.max_abs_m)"
        )


class CsvReference(RefFamily):
    """Linear interpolation of a user file, the same reference for every drone.

    ``max_abs_m`` bounds every position (after ``relative``): a file in mm or in a far-away frame
    is refused rather than trained on. ``time_scale`` stretches time (2.0 = twice as slow);
    ``relative=True`` shifts the path so it starts at the origin (where drones reset); after the
    last row the reference holds the last position unless ``loop=True`` (then it repeats; the
    file should end where it starts).
    """

    ARG_RANGES = {"time_scale": Range(0.0, 100.0, low_open=True), "max_abs_m": Range(0.0, 1e4, low_open=True)}

    def __init__(
        self,
        path: str,
        time_scale: float = 1.0,
        relative: bool = False,
        loop: bool = False,
        max_abs_m: float = 20.0,
    ) -> None:
        check_arg_ranges(CsvReference, locals(), "traj")
        t, pos = load_csv_reference(path)
        self.path = path
        self.t_s = t * time_scale
        self.pos_m = pos - pos[:1] if relative else pos
        check_extent(self.pos_m, max_abs_m, Path(path).name)
        self.loop = loop

    def sample(self, n: int, t_s: Tensor, generator: torch.Generator) -> Tensor:
        query = t_s.double()
        knots_t_s, knots_m = self.t_s.to(query.device), self.pos_m.to(query.device)  # the file: read to the CPU
        if self.loop:
            query = torch.remainder(query, knots_t_s[-1])
        table = piecewise_linear(knots_t_s[None], knots_m[None], query)
        return table.to(t_s.dtype).expand(n, -1, -1)
