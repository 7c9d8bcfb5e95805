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


def summarize(errors: torch.Tensor, crashed: torch.Tensor, leave_out_crashed: bool = True) -> dict:
    """Mean ± std of per-episode errors, and the crash count. ``leave_out_crashed``: the mean
    runs over the episodes that did not crash (all crashed -> mean/std are NaN and the row reads
    "failed" in tables); otherwise over every episode (the authors' accounting)."""
    ok = errors[~crashed] if leave_out_crashed else errors
    mean = ok.mean().item() if len(ok) else math.nan
    std = ok.std(unbiased=False).item() if len(ok) > 1 else (0.0 if len(ok) else math.nan)
    return {
        "mean_m": mean,
        "std_m": std,
        "crashes": int(crashed.sum()),
        "episodes": int(len(errors)),
        "per_episode_m": [round(float(e), 6) for e in errors],
        "per_episode_crashed": [bool(c) for c in crashed],
    }


def format_error(row: dict) -> str:
    if row["episodes"] and row["crashes"] == row["episodes"] and not math.isfinite(row["mean_m"]):
        return "failed"
    text = f"{row['mean_m']:.3f} ± {row['std_m']:.3f}"
    return text + (f" ({row['crashes']} crashed)" if row["crashes"] else "")
