"""PNG plots: reference vs flown tracks, learning curves (matplotlib, Agg backend)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def plot_tracks(trace, names: list[str], counts: list[int], path: str | Path, title: str = "", per_group: int = 2) -> Path:
    """x-y reference (dashed) vs flown track for the first ``per_group`` references of each group."""
    cols = len(names)
    fig, axes = plt.subplots(1, cols, figsize=(4.2 * cols, 4.2), squeeze=False)
    start = 0
    for ax, name, count in zip(axes[0], names, counts):
        for j in range(min(per_group, count)):
            i = start + j
            stop = int(trace.crashed_at[i]) + 1
            ref = trace.ref_m[i, :stop].numpy()
            pos = trace.pos_m[i, :stop].numpy()
            (line,) = ax.plot(ref[:, 0], ref[:, 1], "--", lw=1.0, alpha=0.7)
            ax.plot(pos[:, 0], pos[:, 1], "-", lw=1.4, color=line.get_color(), label=f"#{j}")
        ax.set_title(name)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        start += count
    fig.suptitle(title or "reference (dashed) vs flown (solid)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)


def plot_axes_vs_time(trace, index: int, dt_s: float, path: str | Path, title: str = "") -> Path:
    """x, y, z of reference and flown track against time for one drone."""
    import numpy as np

    pos, ref = trace.pos_m[index].numpy(), trace.ref_m[index].numpy()
    t = np.arange(len(pos)) * dt_s
    fig, axes = plt.subplots(3, 1, figsize=(7, 6), sharex=True)
    for k, ax in enumerate(axes):
        ax.plot(t, ref[:, k], "--", label="reference")
        ax.plot(t, pos[:, k], label="flown")
        ax.set_ylabel("xyz"[k] + " (m)")
        ax.grid(alpha=0.3)
    axes[0].legend()
    axes[-1].set_xlabel("t (s)")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)


def plot_learning_curve(history: list[dict], path: str | Path, title: str = "") -> Path:
    frames = [h["frames"] for h in history]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.6))
    a1.plot(frames, [h["tracking_error_m"] for h in history])
    a1.set_ylabel("mean tracking error (m)")
    a1.set_yscale("log")
    a2.plot(frames, [h["reward_per_step"] for h in history])
    a2.set_ylabel("reward per step")
    for ax in (a1, a2):
        ax.set_xlabel("env steps")
        ax.grid(alpha=0.3)
    fig.suptitle(title or "training")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)
