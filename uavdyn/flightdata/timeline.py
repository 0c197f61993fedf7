"""The import summary figure: the whole flight against time with the kept segments shaded, so a
user sees at a glance what was kept, what was cut and why."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uavdyn.flightdata.segments import SegmentReport
from uavdyn.model import CONTROL_NAMES

SPLIT_COLOURS = {"train": "tab:green", "validation": "tab:orange", "test": "tab:purple",
                 "": "tab:green"}


def draw_timeline(report: SegmentReport, path: str | Path, splits: list[str] | None = None
                  ) -> Path:
    """Write a PNG: roll (with the roll threshold), pitch, speed and the controls against the
    flight's time, kept segments shaded in their split's colour and labelled.

    Parameters
    ----------
    report : SegmentReport
        What the segmenter kept.
    path : str or Path
        The PNG to write (the caller makes it atomic).
    splits : list of str, optional
        The split of each kept segment, in order.

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f = report.flight
    t, c = f.time, f.channels
    splits = splits or [""] * len(report.kept)
    fig, axes = plt.subplots(4, 1, figsize=(10, 8.5), sharex=True, constrained_layout=True)
    limit = report.rules.max_roll_deg
    axes[0].plot(t, np.degrees(c["roll"]), lw=0.8, label="roll")
    axes[0].plot(t, np.degrees(c["r"]), lw=0.8, alpha=0.7, label="yaw rate r (deg/s)")
    for sign in (1, -1):
        axes[0].axhline(sign * limit, color="k", ls=":", lw=0.8)
    axes[0].set_ylabel("roll (deg)")
    axes[1].plot(t, np.degrees(c["pitch"]), lw=0.8, label="pitch")
    axes[1].plot(t, np.degrees(c["q"]), lw=0.6, alpha=0.6, label="q (deg/s)")
    axes[1].set_ylabel("pitch (deg)")
    axes[2].plot(t, c["u"], lw=0.8, label="u")
    axes[2].plot(t, c["w"], lw=0.8, label="w")
    axes[2].set_ylabel("velocity (m/s)")
    for j, name in enumerate(CONTROL_NAMES[f.kind]):
        axes[3].plot(t, f.controls[:, j], lw=0.8, label=name)
    axes[3].set_ylabel("controls")
    axes[3].set_xlabel("time from the start of the imported grid (s)")
    for seg, split in zip(report.kept, splits):
        for ax in axes:
            ax.axvspan(seg.start_s, seg.end_s, color=SPLIT_COLOURS.get(split, "tab:green"),
                       alpha=0.18, lw=0)
        axes[0].annotate(split or "kept", ((seg.start_s + seg.end_s) / 2, 1.0),
                         xycoords=("data", "axes fraction"), ha="center", va="bottom",
                         fontsize=8)
    for ax in axes:
        ax.legend(loc="upper right", fontsize=7, ncol=2)
        ax.grid(alpha=0.3)
    kept = report.kept_s
    fig.suptitle(f"{f.name}: {len(report.kept)} wings-level segment(s), {kept:.1f} s of "
                 f"{f.duration:.1f} s kept\n(|roll| <= {limit:g} deg, |r| <= "
                 f"{report.rules.max_yaw_rate_deg_s:g} deg/s, >= "
                 f"{report.rules.min_duration_s:g} s)", fontsize=10)
    path = Path(path)
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)
    return path
