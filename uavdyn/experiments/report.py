"""Markdown of the validation results: ``report.md`` of ``uavdyn reproduce`` (the headline
first: nominal -> identified -> corrected, every airframe and condition, with spread; error
against horizon, per-sortie results, then Tables 1-4, the work-precision summary and the
figures) and the Markdown of ``uavdyn evaluate`` (:func:`evaluation_markdown`). Every builder
takes the JSON-able result and returns lines.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from uavdyn.experiments.ladder import per_sortie_rmse
from uavdyn.integrate import DEPARTURE_RAD


def fmt(value) -> str:
    """A measured number as the report writes it (3 significant digits; ``n/a`` for None,
    ``diverged`` for a non-finite value; text as it is)."""
    if value is None:
        return "n/a"
    if isinstance(value, str):
        return value
    if value != value or value in (float("inf"), float("-inf")):
        return "diverged"
    return f"{value:.3g}"


def _ci(m: dict) -> str:
    """``0.0113 [0.0019, 0.0182]``: pooled figure and its bootstrap interval."""
    return f"{fmt(m['rmse'])} [{fmt(m['ci_low'])}, {fmt(m['ci_high'])}]"


def corrected_cost_ratio(af: dict) -> dict | None:
    """The corrected step's time over the identified physics step's at the ladder's step size
    (the log interval the correction is scored at), from the cost study's one harness run
    (None if either was not timed there)."""
    same = ((af.get("cost") or {}).get("ratios") or {}).get("vs_physics_same_dt", [])
    dt = (af.get("ladder") or {}).get("dt")
    return next((r for r in same if r["model"] == "corrected"
                 and r["baseline"].startswith("identified physics")
                 and (dt is None or abs(r["dt"] - dt) <= 1e-9 * max(1.0, dt))), None)


PAIRED_WORDS = {"identified_vs_nominal": ("identification", "the nominal physics"),
                "corrected_vs_identified": ("the correction", "the identified physics")}


def _share_sentence(share: dict | None, upper: str, lower: str, interval: bool = True) -> str:
    """`` Identification removes 43 % of the pooled error of ... (share removed +0.43, 95 %
    bootstrap [+0.30, +0.55]).``: the share of the lower rung's pooled error the upper rung
    removes (``error_share``'s dict, negative where it adds), with its bootstrap interval
    (``interval`` False: over one sortie, which has none)."""
    if not share or share["share"] is None:
        return ""
    ci = (f", 95 % bootstrap [{share['ci_low']:+.2f}, {share['ci_high']:+.2f}]"
          if interval and math.isfinite(share["ci_low"]) else "")
    verb = "removes" if share["share"] >= 0 else "adds"
    return (f" {upper[0].upper() + upper[1:]} {verb} {100 * abs(share['share']):.0f} % "
            f"{'of' if share['share'] >= 0 else 'to'} the pooled error of {lower} (share "
            f"removed {share['share']:+.2f}{ci}).")


def _paired_sentence(cmp: dict, upper: str, lower: str, sorties: int) -> str:
    """One sentence of a sortie-by-sortie comparison (``compare_paired``'s dict)."""
    return (_share_sentence(cmp.get("share_removed"), upper, lower, sorties >= 2)
            + f" Against {lower}, {upper} is worse on {len(cmp['worse'])} of {sorties} "
            f"sorties, by more than {100 * cmp['tolerance']:.0f} % on "
            f"{len(cmp['worse_beyond_tolerance'])}"
            + (f" ({', '.join(cmp['worse_beyond_tolerance'])})"
               if cmp["worse_beyond_tolerance"] else "")
            + (f"; it diverges where {lower} does not on {', '.join(cmp['new_divergence'])}"
               if cmp["new_divergence"] else "") + ".")


def headline_lines(af: dict) -> list[str]:
    """The headline bullets of one airframe, from its ladder (computed from the per-sortie
    table only: every figure here can be recomputed from it)."""
    lad = af.get("ladder")
    name = af["airframe"]
    if not lad:
        return [f"- **{name}**: the ladder was not evaluated."]
    lines = []
    for model, why in lad.get("missing", {}).items():
        lines.append(f"- **{name}**: {model} missing ({why}).")
    for entry in lad["headline"]:
        if "missing" in entry:
            lines.append(f"- **{name}, {entry['condition']}**: missing ({entry['missing']}).")
            continue
        models = entry["models"]
        one = entry["sorties"] < 2  # a bootstrap over one sortie is that sortie: no spread
        chain = " -> ".join(f"{m} {fmt(v['rmse']) if one else _ci(v)}"
                            for m, v in models.items())
        text = (f"- **{name}, {entry['condition']}, {entry['label']}** "
                f"({entry['sorties']} test sortie{'s' if entry['sorties'] != 1 else ''}), "
                "pitch RMSE in rad, "
                + ("one sortie, so no interval" if one else
                   "pooled [95 % bootstrap over sorties]") + f": {chain}.")
        if entry["mode"] == "free_run":
            gone = [f"{m} {v['departed']}/{entry['sorties']}" for m, v in models.items()
                    if v.get("departed")]
            if gone:
                text += (f" Free runs whose pitch error passed {DEPARTURE_RAD:g} rad: "
                         + ", ".join(gone) +
                         " (their RMSE is that of a run that has left the data).")
        for key, (upper, lower) in PAIRED_WORDS.items():
            if entry.get(key):
                text += _paired_sentence(entry[key], upper, lower, entry["sorties"])
        lines.append(text)
    ratio = corrected_cost_ratio(af)
    if ratio:
        lines.append(f"- **{name}, cost**: the corrected step costs {ratio['median']:.2f}x the "
                     f"identified physics step at {fmt(lad['dt'])} s (median; min "
                     f"{ratio['min']:.2f}x; compiled free runs, one interleaved timing "
                     "harness, Table 3).")
    return lines


HEADLINE_COLUMNS = ("airframe", "condition", "sorties", "nominal", "identified", "corrected",
                    "identified worse", "corrected worse")


def headline_rows(af: dict, mode: str = "horizon_1s") -> list[tuple[str, ...]]:
    """One row per condition of the ladder's headline at ``mode`` (read from
    ``af["ladder"]["headline"]``, nothing recomputed): each rung's pooled pitch RMSE and, for
    the identified and corrected rungs, on how many sorties it is worse than the rung below
    (``"2/3"``). A missing condition or rung says so."""
    lad = af.get("ladder")
    name = af["airframe"]
    if not lad:
        return [(name, "all", "-", "not evaluated")]
    rows = []
    for entry in lad["headline"]:
        if "missing" in entry:
            rows.append((name, entry["condition"], "0", f"missing: {entry['missing']}"))
            continue
        if entry["mode"] != mode:
            continue
        n = entry["sorties"]
        rmse = [fmt(entry["models"][m]["rmse"]) if m in entry["models"] else "missing"
                for m in ("nominal physics", "identified physics", "corrected")]
        worse = [f"{len(entry[key]['worse'])}/{n}" if entry.get(key) else "-"
                 for key in PAIRED_WORDS]
        rows.append((name, entry["condition"], str(n), *rmse, *worse))
    return rows


def headline_table(results: dict) -> list[str]:
    """The headline of ``uavdyn reproduce`` as a plain-text table for the terminal: 1 s pitch
    RMSE of nominal -> identified -> corrected per airframe and condition, with the sorties
    each rung made worse (:func:`headline_rows`)."""
    rows = [r for af in results["airframes"] for r in headline_rows(af)]
    full = [r for r in rows if len(r) == len(HEADLINE_COLUMNS)]
    widths = [max([len(c)] + [len(r[i]) for r in full]) for i, c in enumerate(HEADLINE_COLUMNS)]

    def line(cells) -> str:
        if len(cells) < len(HEADLINE_COLUMNS):  # a missing group: its reason after the count
            head = "  ".join(c.ljust(w) for c, w in zip(cells[:3], widths))
            return f"{head}  {cells[3]}".rstrip()
        return "  ".join(c.ljust(w) for c, w in zip(cells, widths)).rstrip()

    return (["Does fitting to flight data help? 1 s pitch RMSE (rad), pooled over the held-out "
             "test sorties:", "nominal physics -> identified physics -> corrected (the learned "
             "correction on the identified physics).", "'worse': sorties on which that rung "
             "is worse than the one below it.", "", line(HEADLINE_COLUMNS)]
            + [line(r) for r in rows])


def first_paragraph(results: dict) -> str:
    """The headline: does fitting to flight data help, by how much, at what cost, where does
    it fail: every airframe and condition."""
    lines = ["Nominal physics -> physics identified from the train split -> the safe learned "
             "correction on top of it, scored on held-out test sorties against the emulated "
             "flight data (noise-free states), at the correction's step. 1 s: predictions "
             "restarted from the recorded state every second; free run: the whole sortie from "
             "its first state.", ""]
    for af in results["airframes"]:
        lines += headline_lines(af)
    lines += ["", "Every number in this report was computed by this run. The paper's "
              "published figures (its own, non-public data) appear only in a column labelled "
              "as the paper's, under Tables 1 and 3."]
    return "\n".join(lines)


def per_sortie_lines(af: dict) -> list[str]:
    """Per-sortie pitch RMSE of every model at 1 s and over the free run, and the ratio of
    the corrected model to the identified physics (flagged where it is worse)."""
    lad = af.get("ladder")
    if not lad:
        return []
    models = lad["models"]
    lines = ["| sortie | mission | condition | " + " | ".join(
        f"1 s: {m}" for m in models) + " | " + " | ".join(f"free run: {m}" for m in models)
        + " | corrected / identified (1 s, free run) |",
        "|" + "---|" * (3 + 2 * len(models) + 1)]
    modes = ("horizon_1s", "free_run")
    rmse = {mode: per_sortie_rmse(lad["per_sortie"], mode) for mode in modes}
    seen = dict.fromkeys((r["sortie"], r["mission"], r["condition"]) for r in lad["per_sortie"])
    for sortie, mission, cond in seen:
        vals = {(m, mode): rmse[mode].get(sortie, {}).get(m) for m in models for mode in modes}
        ratios = []
        for mode in modes:
            a, b = vals.get(("identified physics", mode)), vals.get(("corrected", mode))
            ratios.append(b / a if a and b is not None and math.isfinite(a) else None)
        flag = " **worse**" if any(r is not None and r > 1.0 for r in ratios) else ""
        lines.append(f"| {sortie} | {mission} | {cond} | "
                     + " | ".join(fmt(vals[(m, "horizon_1s")]) for m in models) + " | "
                     + " | ".join(fmt(vals[(m, "free_run")]) for m in models)
                     + " | " + ", ".join("n/a" if r is None else "diverged"
                                         if not math.isfinite(r) else f"{r:.4g}"
                                         for r in ratios) + f"{flag} |")
    return lines + [""]


def horizon_lines(af: dict, spread: str = "in the figure and in metrics.json") -> list[str]:
    """Pooled pitch RMSE against horizon, one table per condition, from the ladder
    (``spread``: where the per-sortie spread is)."""
    curves = (af.get("ladder") or {}).get("horizons", {})
    lines = []
    for cond, models in curves.items():
        horizons = [p["horizon_s"] for p in next(iter(models.values()))]
        lines += [f"{cond} test sorties, pooled pitch RMSE (rad) against horizon "
                  f"(per-sortie spread {spread}):", "",
                  "| model | " + " | ".join(f"{h:g} s" for h in horizons) + " |",
                  "|---|" + "---|" * len(horizons)]
        for model, points in models.items():
            lines.append(f"| {model} | " + " | ".join(fmt(p["pooled"]) for p in points) + " |")
        lines.append("")
    return lines


def table1_lines(af: dict) -> list[str]:
    """Table 1 (accuracy), one table per target group, and the paper's own column."""
    lines = []
    for label, table in af["table1"].items():
        lines += [f"#### {label} ({len(table['sorties'])} test sorties)", "",
                  "| solver | one-step theta RMSE | 1 s theta RMSE | free-run theta RMSE | "
                  "free-run theta MAE | free-run theta max | free-run q RMSE | free-run u RMSE |",
                  "|---|---|---|---|---|---|---|---|"]
        for r in table["rows"]:
            fr = r.get("free_run", {})
            lines.append(
                f"| {r['solver']} | {fmt(r.get('one_step', {}).get('theta_rmse'))} | "
                f"{fmt(r.get('horizon_1s', {}).get('theta_rmse'))} | {fmt(fr.get('theta_rmse'))} | "
                f"{fmt(fr.get('theta_mae'))} | {fmt(fr.get('theta_max'))} | "
                f"{fmt(fr.get('q_rmse'))} | {fmt(fr.get('u_rmse'))} |")
        for r in table["rows"]:
            for mode, why in r.get("missing", {}).items():
                lines.append(f"- {r['solver']}, {mode.replace('_', ' ')}: missing ({why})")
            for sortie, dep in r.get("departed", {}).items():
                lines.append(f"- {r['solver']}, free run of {sortie}: departed at "
                             f"t = {dep['time_s']:.2f} s ({dep['what']})")
        lines.append("")
    return lines + ["| metric | the paper's published figure (its own data; not comparable) |",
                    "|---|---|", "| pitch RMSE | 1.82e-3 rad |", "| pitch MAE | 1.47e-3 rad |",
                    "| pitch max error | 2.31e-3 rad |", ""]


def table2_lines(af: dict) -> list[str]:
    """Table 2 (convergence), one definition per column."""
    lines = ["| model | training loss (definition) | epoch 0 or first | final | validation "
             "loss, same definition: epoch 0, best | validation figure (definition) | physics "
             "| epoch 0 | best | epochs | best epoch | kept |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in af["table2"]:
        if "note" in r:
            lines.append(f"| {r['model']} ({r['weights']}) | {r['note']} | | | | | | | | | | |")
            continue
        val_loss = (f"{fmt(r.get('first_val_loss'))}, {fmt(r.get('best_val_loss'))}"
                    if r.get("val_loss_metric") else "not recorded")
        lines.append(f"| {r['model']} ({r['weights']}) | {r['train_metric']} | "
                     f"{fmt(r['first_train_loss'])} | {fmt(r['final_train_loss'])} | "
                     f"{val_loss} | "
                     f"{r['val_metric']} | {fmt(r['physics_val'])} | {fmt(r['initial_val'])} | "
                     f"{fmt(r['best_val'])} | {r['epochs']} | {r['best_epoch']} | "
                     f"{fmt(r.get('kept'))} |")
    return lines + ["", "Each column has the one definition its header gives. The safe "
                    "correction's epoch 0 is the physics itself (zero output), so its "
                    "validation figure equals the physics column.", ""]


def table3_lines(af: dict) -> list[str]:
    """Table 3 (cost) of the cost study, its timing ratios and the paper's own column."""
    c = af.get("cost") or {}
    if not c:
        return ["Not measured.", ""]
    lines = [f"Free runs of `{c['sortie']}` (first {fmt(c.get('segment_s'))} s), {c['grid']}; "
             f"{c['harness']}.", "",
             "| solver | dt (s) | compiled | median (ms) | min (ms) | pitch RMSE vs flight | "
             "pitch RMSE vs reference |", "|---|---|---|---|---|---|---|"]
    for r in c["points"]:
        if not r.get("in_table3", True):
            continue
        lines.append(f"| {r['family']} | {fmt(r['dt'])} | {fmt(r.get('compiled'))} | "
                     f"{fmt(r['median_ms'])} | {fmt(r['min_ms'])} | "
                     f"{fmt(r['theta_rmse_vs_flight'])} | {fmt(r['theta_rmse_vs_reference'])} |")
    for r in c.get("missing", []):
        lines.append(f"| {r.get('family', r.get('solver'))} | {fmt(r.get('dt'))} | | missing: "
                     f"{r['missing']} | | | |")
    ratios = c.get("ratios", {})
    lines += ["", "Ratios from the same harness run (time of the first over the second; "
              "median of medians, min of minima):", ""]
    for r in ratios.get("vs_physics_same_dt", []):
        lines.append(f"- {r['model']} @ {fmt(r['dt'])} s / {r['baseline']}: "
                     f"{r['median']:.3g}x (median), {r['min']:.3g}x (min)")
    for r in ratios.get("vs_fine_rk4", []):
        lines.append(f"- {r['model']} / {r['baseline']}: {r['median']:.3g}x (median), "
                     f"{r['min']:.3g}x (min)")
    return lines + ["", "| solver | the paper's published time (its machine and sortie; not "
                    "comparable) |", "|---|---|", "| RK4 @ 0.001 s | 148 ms |",
                    "| RK4 @ 0.0005 s | 287 ms |", "| hybrid @ 0.005 s | 92 ms |", ""]


def table4_lines(af: dict) -> list[str]:
    """Table 4 (robustness); a scenario without sorties, or a model refused, is missing."""
    lines = ["| scenario | solver | sorties | pitch-error growth (rad/s) | max error before "
             f"divergence (rad) | diverged (error > {DEPARTURE_RAD:g} rad) | "
             "first divergence (s) |",
             "|---|---|---|---|---|---|---|"]
    for r in af["table4"]:
        if not r.get("sorties"):
            lines.append(f"| {r['scenario']} | {r['solver']} | 0 | missing: "
                         f"{r.get('missing', 'no sortie')} | | | |")
            continue
        if "missing" in r:
            lines.append(f"| {r['scenario']} | {r['solver']} | {r['sorties']} | missing: "
                         f"{r['missing']} | | | |")
            continue
        lines.append(f"| {r['scenario']} | {r['solver']} | {r['sorties']} | "
                     f"{fmt(r['slope_rad_per_s'])} | {fmt(r['max_error_rad'])} | "
                     f"{r['diverged']} of {r['sorties']} | {fmt(r.get('first_divergence_s'))} |")
    return lines + [""]


def write_report(results: dict, path: Path) -> Path:
    """Write ``report.md`` (figures linked relative to the report)."""
    path = Path(path)
    lines = ["# uavdyn validation report", "", "## Does fitting to flight data help?", "",
             first_paragraph(results), ""]
    for af in results["airframes"]:
        ds = af["dataset"]
        figs = af.get("figures", {})

        def fig(name, figs=figs):
            return ([f"![{name}]({os.path.relpath(figs[name], path.parent)})", ""]
                    if name in figs else [])

        lines += [f"## {af['airframe']} ({af['kind']})", "",
                  f"Dataset: {ds['sorties']} emulated sorties at {ds['sample_rate_hz']:g} Hz, "
                  f"{len(ds['test_sorties'])} held-out test sorties (split by sortie). "
                  f"Identified physics and correction: "
                  f"{(af.get('identification') or {}).get('source', 'identified in this run')}.",
                  "", "### Prediction error against horizon", ""]
        lines += fig("error_vs_horizon") + horizon_lines(af)
        lines += ["### Per sortie (pitch RMSE, rad)", ""] + per_sortie_lines(af)
        lines += ["### Table 1: accuracy (pitch in rad, q in rad/s, u in m/s)", "",
                  "One-step: one solver step from every recorded state; 1 s: restarted from the "
                  "recorded state every second; free run: whole sortie from its first state. "
                  "Solver steps below the 0.01 s log interval sub-step the logged "
                  "(zero-order-held) control; 0.02 s samples it at its own step.", ""]
        lines += table1_lines(af)
        lines += ["### Table 2: convergence", ""] + table2_lines(af)
        lines += ["### Table 3: cost", ""] + table3_lines(af) + fig("fig5") + fig("work_precision")
        lines += [f"### Table 4: robustness (free run, dt = {fmt(af['ladder']['dt'])} s)", ""]
        lines += table4_lines(af)
        lines += ["### Figures", ""]
        for name in figs:
            if name not in ("error_vs_horizon", "fig5", "work_precision"):
                lines += fig(name)
    lines += [f"Total pipeline wall time: {results.get('wall_s', 0):.0f} s.", ""]
    path.write_text("\n".join(lines))
    return path


def safety_lines(entry: dict) -> list[str]:
    """The per-sortie comparison of one correction with the physics it sits on
    (:func:`uavdyn.experiments.tables.per_sortie_safety`)."""

    def f(v):
        return "n/a" if v is None else f"{v:.4g}"

    lines = ["", f"## Per sortie: {entry['correction']} against {entry['physics']}", "",
             f"Worse than its physics at 1 s on {entry['worse_at_1s']} of "
             f"{len(entry['sorties'])} sorties, over the free run on "
             f"{entry['worse_free_run']}.", "",
             "Ratios compare errors against the truth where the data have it; against "
             "records, with the pitch noise estimated from them (d theta/dt = q) taken off.",
             "",
             "| sortie | condition | 1 s: physics | corrected | ratio | free run: physics "
             "| corrected | ratio | pitch noise taken off | outside envelope "
             "| pitch damping reversed | worse |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in entry["sorties"]:
        outside, reversed_ = r.get("outside_envelope"), r.get("damping_reversed")
        lines.append(
            f"| {r['sortie']} | {r['condition']} | {f(r['horizon_1s_physics'])} | "
            f"{f(r['horizon_1s_corrected'])} | {f(r['horizon_1s_ratio'])} | "
            f"{f(r['free_run_physics'])} | {f(r['free_run_corrected'])} | "
            f"{f(r['free_run_ratio'])} | {r.get('pitch_noise_std', 0.0):.2g} | "
            f"{'n/a' if outside is None else f'{100 * outside:.1f} %'} | "
            f"{'n/a' if reversed_ is None else f'{100 * reversed_:.1f} %'} | "
            f"{'**' + ', '.join(r['worse']) + '**' if r['worse'] else ''} |")
    return lines


def evaluation_markdown(result: dict, figure: str | None = None,
                        json_name: str = "the JSON result") -> str:
    """Markdown of :func:`uavdyn.experiments.evaluate.evaluate_dataset`: the ladder's headline,
    error against horizon and per-sortie table (``figure``: the PNG of the per-sortie 1 s
    pitch RMSE beside it, :func:`uavdyn.experiments.figures.per_sortie_figure`), Table 1,
    Table 4 and the per-sortie comparison of each correction with its physics."""

    lines = [f"# Evaluation of {result['airframe']} on {result['dataset']}", "",
             f"{len(result['sorties'])} sorties ({result['split']}); weights: "
             + (", ".join(result["weights"]) or "none"), ""]
    if result.get("ladder"):
        lines += ["## Headline", "", "Pitch RMSE in rad at the log interval, pooled over the "
                  "sorties of a group [95 % bootstrap over sorties].", ""]
        lines += headline_lines(result) + ["", "## Error against horizon", ""]
        lines += horizon_lines(result, f"in {json_name}, per sortie below")
        lines += ["## Per sortie (pitch RMSE, rad)", ""]
        lines += ([f"![1 s pitch RMSE per sortie]({figure})", ""] if figure else [])
        lines += per_sortie_lines(result)
    lines += ["## Table 1: accuracy", ""]
    lines += table1_lines(result) + ["## Table 4: robustness (free run, dt = 0.005 s)", ""]
    lines += table4_lines(result)
    for entry in result.get("per_sortie", []):
        lines += safety_lines(entry)
    return "\n".join(lines)
