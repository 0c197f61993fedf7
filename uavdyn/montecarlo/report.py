"""What a Monte-Carlo study writes: the per-run table (CSV), the envelopes (CSV), the
exceedance table and figures of the result (JSON, PNG), and a Markdown summary; every file
through a temporary sibling renamed into place. matplotlib is imported only to draw."""

from __future__ import annotations

import json
import math
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from uavdyn.montecarlo.statistics import SIGNAL_LABELS, column_percentiles
from uavdyn.outputs import atomic_file, write_text_atomic

if TYPE_CHECKING:  # pragma: no cover
    from uavdyn.montecarlo.result import MonteCarloResult

METRIC_COLUMNS = ("max_abs_pitch_deg", "max_alpha_deg", "min_airspeed_mps", "max_load_factor",
                  "min_load_factor")
METRIC_LABELS = {"max_abs_pitch_deg": "max |pitch| (deg)", "max_alpha_deg": "max alpha (deg)",
                 "min_airspeed_mps": "min airspeed (m/s)", "max_load_factor": "max load factor",
                 "min_load_factor": "min load factor"}
OUTPUT_FILES = ("summary.csv", "envelopes.csv", "results.json", "summary.md",
                "figures/envelopes.png", "figures/distributions.png")


def _fmt(value: float, digits: int = 4) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) \
        else f"{value:.{digits}g}"


def results_json(result: MonteCarloResult) -> dict:
    """The study's figures as JSON: settings, counts, exceedances, metric percentiles, time."""
    table = result.table
    return {
        "command": "montecarlo", "study": result.spec.describe(),
        "runs": len(table), "trimmed": int((table["trim_ok"] == 1).sum()),
        "diverged": int((table["diverged"] == 1).sum()),
        "exceedance": [e.as_dict() for e in result.exceedance],
        "metric_percentiles": {"percentiles": list(result.envelopes.percentiles),
                               **column_percentiles(table, METRIC_COLUMNS,
                                                    result.envelopes.percentiles)},
        "timing": {"wall_s": result.wall_s, "chunks_computed": len(result.computed),
                   "chunks_reused": len(result.reused), "runs_computed": result.runs_computed,
                   "runs_per_s": result.runs_per_s, "workers": result.workers,
                   "threads": result.threads, "scheduler": result.scheduler},
    }


def control_description(spec) -> str:
    """How the runs are controlled, in words (and the feedback gain when closed loop)."""
    if spec.feedback is None:
        return "open loop (each run flies its commands as they are)"
    gain = "; ".join(", ".join(f"{v:.4g}" for v in row) for row in spec.feedback)
    return ("closed loop: u = trim + deviation - K (x - trim) on u, w, q, theta, K of an LQR "
            f"on the model linearised at the nominal trim (Bryson's rule), K = [{gain}]")


def study_title(result: MonteCarloResult) -> str:
    """The data of a study's figures in one line: airframe, model, input, control, runs,
    duration, dispersions and seed."""
    spec = result.spec
    loop = "open loop" if spec.feedback is None else "closed loop (LQR)"
    return (f"Monte Carlo: {spec.airframe.name}, {spec.model} model, {spec.input_name} input, "
            f"{loop}, {len(result.table)} runs x {spec.duration:g} s, "
            f"{spec.dispersions.origin}, seed {spec.seed}")


def departure_warning(result: MonteCarloResult) -> str | None:
    """One line when most runs of an open-loop study departed (None otherwise)."""
    table, spec = result.table, result.spec
    trimmed = int((table["trim_ok"] == 1).sum())
    departed = int((table["diverged"] == 1).sum())
    if spec.feedback is not None or not trimmed or departed * 2 <= trimmed:
        return None
    return (f"{departed} of {trimmed} runs departed flown open loop: the airframe is open-loop "
            "unstable; fly the study closed loop (closed_loop=True, --closed-loop)")


def summary_markdown(result: MonteCarloResult) -> str:
    """A Markdown page: settings, outcome counts, exceedance table, metric percentiles."""
    spec, table = result.spec, result.table
    n, trimmed = len(table), int((table["trim_ok"] == 1).sum())
    pct = result.envelopes.percentiles
    lines = [
        f"# Monte-Carlo study: {spec.airframe.name}, {n} runs x {spec.duration:g} s", "",
        f"- model: {spec.model}; step {spec.dt:g} s, envelope samples every "
        f"{spec.stride * spec.dt:g} s",
        f"- input: {spec.input_name} (deviations added to each run's own trim command)",
        f"- control: {control_description(spec)}",
        f"- dispersions: {spec.dispersions.origin}; seed {spec.seed} (run k draws from "
        f"default_rng([{spec.seed}, k, 0]), gusts from [{spec.seed}, k, 1])",
        *[f"  - {line}" for line in spec.dispersions.describe()],
        f"- runs: {n}; trimmed {trimmed}; departed or diverged "
        f"{int((table['diverged'] == 1).sum())}",
        *([f"- {departure_warning(result)}"] if departure_warning(result) else []),
        f"- wall time {result.wall_s:.1f} s for {result.runs_computed} computed runs "
        f"({_fmt(result.runs_per_s)} runs/s; {len(result.reused)} chunk(s) reused from an "
        f"earlier run)", "",
        "## Exceedance probabilities", "",
        f"Over the runs that trimmed; a diverged run counts as exceeding. Wilson "
        f"{100 * result.exceedance[0].confidence:g} % intervals.", "",
        "| event | runs | count | probability | interval |", "|---|---|---|---|---|"]
    for e in result.exceedance:
        lines.append(f"| {e.event} | {e.runs} | {e.count} | {_fmt(e.probability)} | "
                     f"[{_fmt(e.low)}, {_fmt(e.high)}] |")
    lines += ["", f"## Per-run metrics (percentiles {', '.join(f'{p:g}' for p in pct)} over "
                  "runs that trimmed and did not diverge)", "",
              "| metric | " + " | ".join(f"p{p:g}" for p in pct) + " |",
              "|---|" + "---|" * len(pct)]
    for column, values in column_percentiles(table, METRIC_COLUMNS, pct).items():
        lines.append(f"| {column} | " + " | ".join(_fmt(v) for v in values) + " |")
    lines += ["", "## Files", "",
              "- `summary.csv`: one row per run (outcomes, then each drawn quantity; empty "
              "cell = not applicable: `t_diverged_s` of a run that did not diverge, outcomes "
              "of a run that did not trim)",
              f"- `envelopes.csv`: percentiles of the time histories over "
              f"{result.envelopes.n_runs} runs",
              "- `results.json`: these figures; `study.json`: the settings and study key",
              "- `chunks/`: the raw chunk files (a re-run with the same settings resumes from "
              "them)", "",
              "![envelopes](figures/envelopes.png)", "",
              "![distributions](figures/distributions.png)", ""]
    return "\n".join(lines)


def prepare_figures() -> None:
    """Import matplotlib now (e.g. in a thread while the last chunks run); errors are left to
    the figure functions."""
    try:
        _pyplot()
    except Exception:  # pragma: no cover - reported when a figure is drawn
        pass


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path, margins: dict[str, float]) -> None:
    """Save with fixed margins (figure fractions): ``tight_layout`` measured every tick label
    and took as long as drawing the figure."""
    plt = _pyplot()
    fig.subplots_adjust(**margins)
    with atomic_file(path) as tmp, open(tmp, "wb") as fh:
        fig.savefig(fh, dpi=100, format="png")
    plt.close(fig)


def envelope_figure(result: MonteCarloResult, path: Path) -> Path:
    """Percentile bands of every signal against time, with the active limits."""
    plt = _pyplot()
    env = result.envelopes
    fig, axes = plt.subplots(len(env.signals), 1, figsize=(8, 2.1 * len(env.signals)),
                             sharex=True)
    pitch, alpha, speed, load = result.spec.limits
    limit_lines = {"theta": [math.degrees(pitch), -math.degrees(pitch)],
                   "alpha": [math.degrees(alpha)], "airspeed": [speed], "load_factor": [load]}
    lo, mid, hi = (env.percentiles.index(p) if p in env.percentiles else None
                   for p in (5.0, 50.0, 95.0))
    for ax, signal in zip(axes, env.signals):
        band = env.band(signal)
        if lo is not None and hi is not None:
            ax.fill_between(env.time, band[lo], band[hi], color="C0", alpha=0.3,
                            label="5-95 %")
        if mid is not None:
            ax.plot(env.time, band[mid], "C0-", lw=1.2, label="median")
        for value in limit_lines.get(signal, []):
            if math.isfinite(value):
                ax.axhline(value, color="C3", ls="--", lw=0.8)
        label, unit = SIGNAL_LABELS[signal]
        ax.set_ylabel(f"{label}\n({unit})")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    fig.suptitle(textwrap.fill(f"{study_title(result)}; percentile envelopes over the "
                               f"{env.n_runs} runs that trimmed; dashed red: limits", 95),
                 fontsize=9)
    axes[-1].set_xlabel("time (s)")
    _save(fig, path, {"left": 0.11, "right": 0.98, "bottom": 0.05,
                      "top": 1 - 0.75 / fig.get_figheight(), "hspace": 0.12})
    return path


def _histogram_range(values: np.ndarray) -> tuple[float, float]:
    """The x range of a histogram: the values' own, widened where they (nearly) coincide so
    the bins have a finite width (a few runs of a narrow dispersion can agree to the last
    digits, which numpy cannot bin)."""
    lo, hi = float(np.min(values)), float(np.max(values))
    pad = max(1e-6 * max(abs(lo), abs(hi), 1.0), 0.0)
    return (lo - pad, hi + pad) if hi - lo < pad else (lo, hi)


def distribution_figure(result: MonteCarloResult, path: Path) -> Path:
    """Histograms of the per-run metrics, with the active limits."""
    plt = _pyplot()
    table = result.table
    keep = (table["trim_ok"] == 1) & (table["diverged"] == 0)
    pitch, alpha, speed, load = result.spec.limits
    limits = {"max_abs_pitch_deg": math.degrees(pitch), "max_alpha_deg": math.degrees(alpha),
              "min_airspeed_mps": speed, "max_load_factor": load}
    fig, axes = plt.subplots(1, len(METRIC_COLUMNS), figsize=(3.2 * len(METRIC_COLUMNS), 3.4))
    for ax, column in zip(axes, METRIC_COLUMNS):
        values = table[column][keep]
        if len(values):
            ax.hist(values, bins=min(50, max(5, len(values) // 20)), color="C0", alpha=0.8,
                    range=_histogram_range(values))
            # a rug: a narrow spread far from its limit draws bars too thin to see
            ax.plot(values, np.zeros(len(values)), "|", color="C0", ms=14, mew=1.5)
            ax.set_title(f"range {_fmt(float(np.min(values)))} to "
                         f"{_fmt(float(np.max(values)))}", fontsize=8)
        if column in limits and math.isfinite(limits[column]):
            ax.axvline(limits[column], color="C3", ls="--", lw=1)
        ax.set_xlabel(METRIC_LABELS.get(column, column))
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("runs")
    fig.suptitle(f"{study_title(result)}\nper-run extremes of the {int(keep.sum())} runs that "
                 "trimmed and did not diverge; dashed red: limits", fontsize=9)
    _save(fig, path, {"left": 0.045, "right": 0.99, "bottom": 0.16, "top": 0.78,
                      "wspace": 0.22})
    return path


def write_outputs(result: MonteCarloResult, folder: str | Path) -> dict[str, str]:
    """Write the table, envelopes, JSON, Markdown and figures into ``folder``; returns the
    paths by name."""
    folder = Path(folder)
    paths = {name: folder / name for name in OUTPUT_FILES}
    write_text_atomic(paths["summary.csv"], result.table.csv_text())
    write_text_atomic(paths["envelopes.csv"], result.envelopes.csv_text())
    write_text_atomic(paths["results.json"], json_text(results_json(result)))
    (folder / "figures").mkdir(exist_ok=True)
    envelope_figure(result, paths["figures/envelopes.png"])
    distribution_figure(result, paths["figures/distributions.png"])
    write_text_atomic(paths["summary.md"], summary_markdown(result))
    return {name: str(path) for name, path in paths.items()}


def _clean(value: object) -> object:
    """JSON-safe copy: NumPy scalars as numbers, non-finite floats as null."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


def json_text(doc: dict) -> str:
    """Strict JSON text (no NaN or Infinity tokens) of ``doc``."""
    return json.dumps(_clean(doc), indent=2, allow_nan=False) + "\n"
