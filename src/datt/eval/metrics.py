"""Tracking metrics (paper §3): mean over an episode of ‖p_t − p^d_t‖, crash accounting."""

from __future__ import annotations

import math

import torch


def episode_errors(err_m: torch.Tensor, crashed_at: torch.Tensor) -> torch.Tensor:
    """Mean tracking error per drone over the steps it flew.

    ``err_m [N, T]`` per-step ‖p − p_d‖ (m); ``crashed_at [N]`` index of the step at which the
    drone terminated (T if it never did). Steps after a crash are not counted.
    """
    t = torch.arange(err_m.shape[1], device=err_m.device)
    flown = t[None, :] <= crashed_at[:, None].clamp_max(err_m.shape[1] - 1)
    return (err_m * flown).sum(1) / flown.sum(1).clamp_min(1)


DIVERGED_WINDOW_S = 1.0  # the end of an episode over which divergence is judged


def diverged_episodes(err_m: torch.Tensor, crashed_at: torch.Tensor, dt_s: float, threshold_m: float) -> torch.Tensor:
    """The paper's "failed: the drone diverges from the reference", per episode ``[N]``: it
    crashed (left the safety box, or passed the error limit where the protocol has one), or its
    error over the last :data:`DIVERGED_WINDOW_S` of the episode averages above ``threshold_m``.
    ``err_m [N, T]`` per-step ‖p − p_d‖; ``crashed_at [N]`` as in :func:`episode_errors`."""
    window = max(1, min(err_m.shape[1], round(DIVERGED_WINDOW_S / dt_s)))
    crashed = crashed_at < err_m.shape[1]
    return crashed | (err_m[:, -window:].mean(1) > threshold_m)


def summarize(
    errors: torch.Tensor, crashed: torch.Tensor, leave_out_crashed: bool = True, diverged: torch.Tensor | None = None
) -> dict:
    """Mean ± std of per-episode errors, and the crash count. ``leave_out_crashed``: the mean
    runs over the episodes that did not crash (all crashed -> mean/std are NaN and the row reads
    "failed" in tables); otherwise over every episode (the authors' accounting). ``diverged``
    (:func:`diverged_episodes`, default: the crashed ones) is counted beside them."""
    diverged = crashed if diverged is None else diverged
    ok = errors[~crashed] if leave_out_crashed else errors
    mean = ok.mean().item() if len(ok) else math.nan
    std = ok.std(unbiased=False).item() if len(ok) > 1 else (0.0 if len(ok) else math.nan)
    return {
        "mean_m": mean,
        "std_m": std,
        "crashes": int(crashed.sum()),
        "diverged": int(diverged.sum()),
        "episodes": int(len(errors)),
        "per_episode_m": [round(float(e), 6) for e in errors],
        "per_episode_crashed": [bool(c) for c in crashed],
        "per_episode_diverged": [bool(d) for d in diverged],
    }


def run_failed(row: dict) -> bool:
    """A run failed on a group (the paper's "failed") when most of its episodes diverged.
    Rows written before the divergence count: when every episode crashed."""
    episodes = row["episodes"]
    diverged = row.get("diverged", row["crashes"] if row["crashes"] == episodes else 0)
    return episodes > 0 and diverged * 2 > episodes


def format_error(row: dict) -> str:
    if row["episodes"] and row["crashes"] == row["episodes"] and not math.isfinite(row["mean_m"]):
        return "failed"
    text = f"{row['mean_m']:.3f} ± {row['std_m']:.3f}"
    notes = [f"{row['crashes']} crashed"] if row["crashes"] else []
    if row.get("diverged", 0) > row["crashes"]:
        notes.append(f"{row['diverged']} diverged")
    text += f" ({', '.join(notes)})" if notes else ""
    return text + (" failed" if run_failed(row) else "")
