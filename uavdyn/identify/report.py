"""What ``uavdyn identify`` writes: the fitted airframe as a complete TOML file with a provenance
comment, and a report (JSON + PNG) of the estimates, their correlations and the fit per sortie."""

from __future__ import annotations

import datetime as _dt
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from uavdyn.airframes import OPTIONAL_PARAMS, Airframe, param_names
from uavdyn.airframes.params import LATERAL_PARAMS
from uavdyn.identify.output_error import IdentificationResult
from uavdyn.identify.result import Estimate
from uavdyn.outputs import atomic_file, write_text_atomic


def _toml_string(text: str) -> str:
    return json.dumps(str(text), ensure_ascii=False)  # a JSON string is a TOML basic string


def _toml_number(value: float) -> str:
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"cannot write the non-finite number {number!r} to an airframe file")
    return repr(number)


def _toml_array(values) -> str:
    return "[" + ", ".join(_toml_number(v) for v in values) + "]"


def airframe_toml(airframe: Airframe, header: list[str]) -> str:
    """A complete airframe file (the loader's schema) with ``header`` as comment lines: every
    parameter of the kind (an optional one where it differs from its no-effect default), the
    atmosphere, ``[limits]``, ``[delays]`` and ``[tables]`` with their values, so that
    :func:`uavdyn.airframes.load_airframe` gives back the same ``p``, delays and structure."""
    lines = [f"# {h}" for h in header] + [
        "", f"name = {_toml_string(airframe.name)}", f"kind = {_toml_string(airframe.kind)}",
        f"description = {_toml_string(airframe.description)}",
        f"nominal_airspeed = {_toml_number(airframe.nominal_airspeed)}"]
    if airframe.atmosphere != "constant":
        lines.append(f"atmosphere = {_toml_string(airframe.atmosphere)}")
    if airframe.relaxed_stability:
        lines.append("relaxed_stability = true")
    lines.append("")
    optional = {**OPTIONAL_PARAMS[airframe.kind], **dict.fromkeys(LATERAL_PARAMS, 0.0)}
    for name in param_names(airframe.kind) + LATERAL_PARAMS:
        value = float(getattr(airframe.params, name))
        if name in optional and value == optional[name]:
            continue  # absent = its default, which changes nothing
        lines += [f"[params.{name}]", f"value = {_toml_number(value)}",
                  f"source = {_toml_string(airframe.sources.get(name, ''))}"]
    if airframe.limits:
        lines += ["", "[limits]"]
        for key, value in airframe.limits.items():
            text = (_toml_array(value) if isinstance(value, (tuple, list))
                    else _toml_number(value))
            lines.append(f"{key} = {text}")
    delays = {k: int(v) for k, v in airframe.delays.items() if v}
    if delays:
        lines += ["", "[delays]"] + [f"{k} = {v}" for k, v in delays.items()]
    for name in sorted(airframe.tables):
        table = airframe.tables[name]
        lines += ["", f"[tables.{name}]"]
        lines += [f"{axis} = {_toml_array(points)}" for axis, points in table.axes]
        if len(table.axes) == 1:
            lines.append(f"values = {_toml_array(table.values)}")
        else:
            n1 = table.shape[1]
            rows = [_toml_array(table.values[i * n1:(i + 1) * n1])
                    for i in range(table.shape[0])]
            lines.append("values = [\n    " + ",\n    ".join(rows) + ",\n]")
    return "\n".join(lines) + "\n"


def provenance(result: IdentificationResult, nominal: Airframe, dataset: str, command: str
               ) -> list[str]:
    """Header lines saying where the identified numbers come from."""
    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    interval = result.dt * result.substeps
    lines = [f"Identified by uavdyn from '{nominal.name}' on {date}",
             f"dataset: {dataset}", f"command: {command}",
             f"output-error fit over {result.fit['windows']} windows of {result.window_s:g} s "
             f"restarted from recorded states, RK4 {result.substeps} x {result.dt:g} s per "
             f"{interval:g} s sample, {result.iterations} Levenberg-Marquardt iterations "
             f"({result.fit['solver_status']})"]
    left = result.fit.get("left_out")
    if left:
        lines.append(f"  left out of the fit: {left['windows']} of {left['of']} windows "
                     f"({', '.join(left['sorties'])}): {left['why']}")
    if nominal.atmosphere == "isa":
        lines.append("  atmosphere isa: rho is the sea-level density, scaled per sortie by the "
                     "standard atmosphere at its manifest altitude_m")
    for e in result.estimates:
        if e.searched:
            edge = ", the largest searched" if e.at_bound else ""
            ms = 1000 * int(e.value) * interval
            lines.append(f"  {e.name} = {int(e.value)} samples ({ms:g} ms; searched integer"
                         f"{edge}, nominal {int(e.nominal)})")
            continue
        lines.append("  " + estimate_line(e))
    for a, b, c in result.flagged_pairs:
        lines.append(f"  highly correlated: {a} and {b} (r = {c:+.3f})")
    prior = next((s for s in result.search if s.get("step") == "prior"), None)
    if prior:
        lines.append(f"  prior: Gaussian around the file's values, relative s.d. "
                     f"{prior['relative_sd']:g} (maximum a posteriori)")
    kept = [e.name for e in result.estimates if e.kept]
    if kept:
        lines.append(f"  kept the file's value (not determined by these data): "
                     f"{', '.join(kept)}")
    held = [e.name for e in result.estimates if e.held]
    if held:
        lines.append(f"  {HELD_HEADLINE}: {', '.join(held)}")
    free = result.fit.get("free_run")
    if free:
        lines.append(f"  free run of the {len(free['per_sortie'])} train sorties (pitch error "
                     f"past {free['departure_rad']:g} rad): identified departs on "
                     f"{len(free['identified_departed'])}, nominal on "
                     f"{len(free['nominal_departed'])}")
    return lines


HELD_HEADLINE = ("fitted with the combination their data cannot determine held at the file's "
                 "values (the rest from the data)")


def estimate_line(e: Estimate) -> str:
    """One estimate as a person reads it: value, corrected and Cramer-Rao standard errors,
    nominal, and what makes it unreliable (the data cannot determine it, the bound)."""
    change = ("" if not math.isfinite(e.relative_change)
              else f", {100 * e.relative_change:+.2f} %")
    text = (f"{e.name} = {e.value:.6g} +- {e.std_error_corrected:.2g} (1 s.e. corrected for "
            f"correlated residuals; Cramer-Rao {e.std_error:.2g}; nominal {e.nominal:.6g}"
            f"{change})")
    flags = e.flags()
    if e.kept:
        fit = "0" if abs(e.data_value) < 1e-300 else f"{e.data_value:.6g}"  # a sign bound
        return (f"{e.name} = {e.value:.6g}: the airframe file's value, KEPT: not determined by "
                f"these data ({'; '.join(flags)}; the fit gave {fit} +- "
                f"{e.std_error_corrected:.2g})"
                + (f". Would need: {e.excitation}" if e.excitation else ""))
    if e.pull():
        text = text[:-1] + f"; {e.pull()})"
    if e.undetermined:
        text += (" NOT DETERMINED by these data" + (", SET UNDER THE PRIOR" if e.pull() else "")
                 + (" alone, FITTED WITH ITS GROUP HELD" if e.held else "")
                 + ": " + "; ".join(flags) + (f"; {e.held}" if e.held else ""))
        text += f". Would need: {e.excitation}"
    elif flags:
        text += " FLAGGED: " + "; ".join(flags)
    return text


def identified_airframe(result: IdentificationResult, nominal: Airframe, dataset: str,
                        command: str) -> Airframe:
    """The fitted airframe with each estimated parameter's source saying so."""
    sources = dict(result.airframe.sources)
    for e in result.estimates:
        if e.searched or e.name not in param_names(nominal.kind):
            continue  # delays and table values have no source entry
        flags = f"; {'; '.join(e.flags())}" if e.flags() else ""
        if e.kept:
            sources[e.name] = (f"{e.kept}; not identified from {dataset}; was: "
                               f"{nominal.sources.get(e.name, '')}")
            continue
        if e.pull():
            flags += f"; maximum a posteriori, {e.pull()}"
        if e.held:
            flags += f"; {e.held}"
        sources[e.name] = (f"identified from {dataset}: {e.value:.6g} +- "
                           f"{e.std_error_corrected:.2g} (corrected s.e.{flags}; nominal "
                           f"{e.nominal:.6g}; was: {nominal.sources.get(e.name, '')})")
    return replace(result.airframe, name=f"{nominal.name}_identified", sources=sources,
                   description=f"{nominal.description} (parameters identified from flight "
                               f"data)".strip())


def structure_lines(log: list[dict]) -> list[str]:
    """What ``--structure auto`` tried, its effect and what it kept."""
    lines = ["structure chosen from the data (uavdyn identify --structure auto): criterion "
             "validation 1 s pitch RMSE, a term kept when it lowers it by >= 2 %"]
    for e in log:
        if "refused" in e:
            lines.append(f"  {e['step']}: not fitted ({e['refused']})")
        elif e["step"] == "base":
            lines.append(f"  base ({', '.join(e['terms'])}): "
                         f"{e['validation_theta_rmse']:.4g} rad")
        else:
            lines.append(f"  {'KEPT' if e['kept'] else 'tried'} {e['step']} ({e['what']}): "
                         f"{e['validation_theta_rmse']:.4g} rad against {e['against']:.4g}")
    return lines


def write_outputs(result: IdentificationResult, nominal: Airframe, dataset: str, command: str,
                  out: Path, report_dir: Path, structure_log: list[dict] | None = None
                  ) -> dict[str, Path]:
    """Write the airframe file and the report (JSON, PNG) atomically; return their paths."""
    fitted = identified_airframe(result, nominal, dataset, command)
    header = provenance(result, nominal, dataset, command)
    if structure_log:
        header += structure_lines(structure_log)
    write_text_atomic(out, airframe_toml(fitted, header))
    report_dir.mkdir(parents=True, exist_ok=True)
    doc = {"command": "identify", "dataset": dataset, "invocation": command,
           "airframe_file": str(out), **result.to_dict(),
           **({"structure": structure_log} if structure_log else {})}
    json_path = write_text_atomic(report_dir / "identify.json", json.dumps(doc, indent=2) + "\n")
    png = _plot(result, report_dir / "identify.png",
                f"Output-error identification of {nominal.name} on {dataset} (fitted on the "
                f"train split, checked on validation; {result.window_s:g} s windows)")
    return {"airframe": out, "json": json_path, "png": png}


def _plot(result: IdentificationResult, path: Path, title: str = "") -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.8), constrained_layout=True)
    if title:
        fig.suptitle(title, fontsize=10, wrap=True)
    est = result.estimates
    ax = axes[0]
    rel = [100 * e.relative_change if math.isfinite(e.relative_change) else 0.0 for e in est]
    err = [100 * e.std_error_corrected / abs(e.nominal) if e.nominal and not e.searched
           else 0.0 for e in est]
    ax.barh([e.name for e in est], rel, xerr=[2 * v for v in err], color="C0", capsize=4)
    for i, e in enumerate(est):  # no relative change from a nominal 0: the value is written
        if not math.isfinite(e.relative_change):
            text = f"{int(e.value)} samples" if e.searched else f"{e.value:.4g} (from 0)"
            ax.text(0, i, " " + text, va="center", fontsize=8)
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("change from nominal (%); bars: +-2 corrected standard errors")
    ax.set_title("estimates against the nominal airframe", fontsize=10)
    ax = axes[1]
    names = result.fitted_names
    im = ax.imshow(result.correlation if names else np.zeros((1, 1)), vmin=-1, vmax=1,
                   cmap="coolwarm")
    ax.set_xticks(range(len(names)), names, rotation=45, ha="right", fontsize=8)
    ax.set_yticks(range(len(names)), names, fontsize=8)
    for i in range(len(names)):
        for j in range(len(names)):
            ax.text(j, i, f"{result.correlation[i, j]:.2f}", ha="center", va="center",
                    fontsize=7)
    fig.colorbar(im, ax=ax, fraction=0.046)
    ax.set_title("correlation of the estimates", fontsize=10)
    ax = axes[2]
    for split, marker in (("train", "o"), ("validation", "s")):
        part = result.fit.get(split)
        if not part:
            continue
        rows = part["per_sortie"]
        nominal = [r["theta_rmse_nominal"] for r in rows]
        fitted = [r["theta_rmse_identified"] for r in rows]
        ax.loglog(nominal, fitted, marker, label=f"{split} sorties", alpha=0.8)
    lim = ax.get_xlim()
    ax.plot(lim, lim, "k:", lw=0.8, label="no change")
    for axis in (ax.xaxis, ax.yaxis):  # 1-2-5 ticks as plain numbers, minor ones unlabelled
        axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:.3g}"))
        axis.set_minor_formatter(NullFormatter())
    ax.set_xlabel(f"pitch RMSE, nominal ({result.window_s:g} s windows, rad)")
    ax.set_ylabel("pitch RMSE, identified (rad)")
    ax.set_title("pitch RMSE per sortie (below the line: better)", fontsize=10)
    ax.legend(fontsize=8)
    with atomic_file(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)
    return path


