"""PNG plots: reference vs flown tracks, disturbance estimates, learning curves (matplotlib, Agg backend)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def plot_tracks(
    trace, names: list[str], counts: list[int], path: str | Path, title: str = "", per_group: int = 2
) -> Path:
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


def _first_of_groups(counts: list[int]) -> list[int]:
    return [sum(counts[:g]) for g in range(len(counts))]


def plot_group_axes(trace, names: list[str], counts: list[int], dt_s: float, path: str | Path, title: str = "") -> Path:
    """x, y, z against time (reference dashed, flown solid) for the first reference of each group:
    one column per group, one row per axis."""
    import numpy as np

    fig, axes = plt.subplots(3, len(names), figsize=(4.2 * len(names), 6.0), sharex=True, squeeze=False)
    for col, (name, i) in enumerate(zip(names, _first_of_groups(counts))):
        stop = int(trace.crashed_at[i]) + 1
        pos, ref = trace.pos_m[i, :stop].numpy(), trace.ref_m[i, :stop].numpy()
        t = np.arange(len(pos)) * dt_s
        for k in range(3):
            ax = axes[k, col]
            ax.plot(t, ref[:, k], "--", lw=1.0, label="reference")
            ax.plot(t, pos[:, k], lw=1.3, label="flown")
            ax.grid(alpha=0.3)
            if col == 0:
                ax.set_ylabel("xyz"[k] + " (m)")
        axes[0, col].set_title(f"{name} #0")
        axes[-1, col].set_xlabel("t (s)")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(title or "per-axis tracking")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)


def plot_disturbance_estimate(
    trace, names: list[str], counts: list[int], dt_s: float, path: str | Path, title: str = ""
) -> Path:
    """The disturbance d (dashed) and the controller's estimate d̂ (solid), m/s², against time
    for the first reference of each group: one column per group, one row per world axis (the
    paper's d̂ traces)."""
    fig = disturbance_estimate_figure(trace, names, counts, dt_s, title)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)


def disturbance_estimate_figure(trace, names: list[str], counts: list[int], dt_s: float, title: str = ""):
    """The figure of :func:`plot_disturbance_estimate` (axes ``[axis row][group column]``, lines
    d then d̂), not yet saved."""
    import numpy as np

    fig, axes = plt.subplots(3, len(names), figsize=(4.2 * len(names), 6.0), sharex=True, squeeze=False)
    for col, (name, i) in enumerate(zip(names, _first_of_groups(counts))):
        stop = int(trace.crashed_at[i])
        d, d_hat = trace.d_mps2[i, :stop].numpy(), trace.d_hat[i, :stop].numpy()
        t = np.arange(1, len(d) + 1) * dt_s
        for k in range(3):
            ax = axes[k, col]
            ax.plot(t, d[:, k], "--", lw=1.0, label="$d$")
            ax.plot(t, d_hat[:, k], lw=1.2, label=r"$\hat{d}$")  # mathtext: the font drops a combining hat
            ax.grid(alpha=0.3)
            if col == 0:
                ax.set_ylabel(f"{'xyz'[k]} (m/s²)")
        axes[0, col].set_title(f"{name} #0")
        axes[-1, col].set_xlabel("t (s)")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(title or "disturbance and its estimate")
    fig.tight_layout()
    return fig


def plot_side_by_side(traces: dict, index: int, dt_s: float, path: str | Path, title: str = "") -> Path:
    """Several controllers on the same reference (drone ``index`` of each trace): x-y tracks on
    the left, tracking error against time on the right."""
    import numpy as np

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.4))
    first = next(iter(traces.values()))
    ref = first.ref_m[index].numpy()
    a1.plot(ref[:, 0], ref[:, 1], "k--", lw=1.0, label="reference")
    for name, trace in traces.items():
        stop = int(trace.crashed_at[index]) + 1
        pos = trace.pos_m[index, :stop].numpy()
        a1.plot(pos[:, 0], pos[:, 1], lw=1.2, label=name)
        err = trace.err_m[index, :stop].numpy()
        a2.plot(np.arange(1, len(err) + 1) * dt_s, err, lw=1.0, label=f"{name} ({err.mean():.3f} m)")
    a1.set_xlabel("x (m)")
    a1.set_ylabel("y (m)")
    a1.set_aspect("equal", adjustable="datalim")
    a2.set_xlabel("t (s)")
    a2.set_ylabel("‖p − p_d‖ (m)")
    for ax in (a1, a2):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title or "controllers on one reference")
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
