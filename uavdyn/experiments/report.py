"""Markdown report of the validation pipeline: headline first (measured against the paper's
figures), then Tables 1-4, the work-precision summary and the figures.
"""

from __future__ import annotations

import os
from pathlib import Path


def _e(value) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, str):
        return value
    if value != value or value in (float("inf"), float("-inf")):
        return "diverged"
    return f"{value:.3g}"


def _row(table: dict, solver: str) -> dict | None:
    return next((r for r in table["rows"] if r["solver"] == solver), None)


def headline(af: dict) -> dict:
    """The measured numbers the first paragraph quotes, for one airframe."""
    t1 = af["table1"]
    group = next((g for g in ("flight data (calm)", "flight data", "flight data (turbulent)")
                  if g in t1), None)
    calm = t1.get(group) if group else None
    # fixed wing: whole-sortie free run; quadrotor (neutrally stable in pitch open loop):
    # 1 s predictions restarted from the recorded state
    mode = "free_run" if af["kind"] == "fixed_wing" else "horizon_1s"
    out = {"airframe": af["airframe"], "mode": mode, "group": group}
    if calm:
        for key, name in (("rk4", "RK4 nominal physics @ 0.005 s"),
                          ("identified", "RK4 identified physics @ 0.005 s"),
                          ("hybrid_identified", "hybrid improved on identified physics @ 0.005 s"),
                          ("hybrid", "hybrid improved @ 0.005 s"),
                          ("paper_form", "hybrid paper @ 0.005 s")):
            row = _row(calm, name)
            if row and mode in row:
                out[f"{key}_rmse"] = row[mode]["theta_rmse"]
                out[f"{key}_mae"] = row[mode]["theta_mae"]
                out[f"{key}_max"] = row[mode]["theta_max"]
                out[f"{key}_one_step_rmse"] = row["one_step"]["theta_rmse"]
    wp = af["work_precision"]
    hyb = next((p for p in wp if p["family"] == "hybrid improved" and p["dt"] == 0.005), None)
    rk4 = sorted((p for p in wp if p["family"] == "RK4"), key=lambda p: p["wall_ms"])
    if hyb:
        equal = [p for p in rk4 if p["theta_rmse_vs_flight"] <= hyb["theta_rmse_vs_flight"]]
        out["hybrid_wall_ms"] = hyb["wall_ms"]
        out["rk4_equal_accuracy"] = equal[0] if equal else None
        if equal:
            out["speedup_equal_accuracy"] = 1 - hyb["wall_ms"] / equal[0]["wall_ms"]
        rk4_fine = next((p for p in rk4 if p["dt"] == 0.001), None)
        if rk4_fine:
            out["cost_reduction_vs_rk4_0.001"] = 1 - hyb["wall_ms"] / rk4_fine["wall_ms"]
            out["rk4_0.001_rmse_vs_flight"] = rk4_fine["theta_rmse_vs_flight"]
    num = next((p for p in wp if p["family"] == "hybrid improved (numerical)"
                and p["dt"] == 0.005), None)
    if num:
        equal = [p for p in rk4 if p["theta_rmse_vs_reference"] <= num["theta_rmse_vs_reference"]]
        out["numerical_hybrid"] = num
        out["numerical_rk4_equal"] = equal[0] if equal else None
        if equal:
            out["numerical_speedup"] = 1 - num["wall_ms"] / equal[0]["wall_ms"]
    return out


def first_paragraph(results: dict) -> str:
    paper = results["paper"]
    parts = []
    for af in results["airframes"]:
        h = headline(af)
        if "hybrid_rmse" not in h:
            parts.append(f"**{h['airframe']}**: no hybrid weights available, physics-only RK4 "
                         f"pitch RMSE {_e(h.get('rk4_rmse'))} rad.")
            continue
        ratio = h["rk4_rmse"] / h["hybrid_rmse"] if h["hybrid_rmse"] else float("inf")
        how = ("free run over whole sorties" if h["mode"] == "free_run" else
               "1 s predictions restarted from the recorded state, since an open-loop "
               "quadrotor is neutrally stable in pitch")
        which = (h["group"] or "").replace("flight data", "").strip(" ()") or "all"
        text = (f"**{h['airframe']}** ({which} test sorties, {how}, at "
                f"dt = 0.005 s, against the emulated flight data): hybrid pitch RMSE "
                f"**{_e(h['hybrid_rmse'])} rad** (MAE {_e(h['hybrid_mae'])}, max "
                f"{_e(h['hybrid_max'])}) against physics-only RK4 **{_e(h['rk4_rmse'])} rad** "
                f"({ratio:.1f}x lower) and the paper's 1.82e-3 rad. ")
        if "identified_rmse" in h:
            text += (f"Physics identified on the train split (`uavdyn identify`, no learning) "
                     f"gives **{_e(h['identified_rmse'])} rad**")
            text += (f", and the correction trained on top of it "
                     f"**{_e(h['hybrid_identified_rmse'])} rad**. "
                     if "hybrid_identified_rmse" in h else ". ")
        if h.get("rk4_equal_accuracy"):
            text += (f"At equal accuracy the hybrid saves "
                     f"**{100 * h['speedup_equal_accuracy']:.0f} %** of the cost of the plain RK4 "
                     f"step that matches it (paper: {100 * paper['cost_reduction']:.0f} %). ")
        else:
            text += ("No plain RK4 step size reaches the hybrid's accuracy against the flight "
                     "data at any cost (the remaining RK4 error is model discrepancy, not step "
                     "size), so a speed-up at equal accuracy does not exist here; against the "
                     "paper's comparison (hybrid at 0.005 s vs RK4 at 0.001 s) the hybrid costs "
                     f"{100 * (1 - h.get('cost_reduction_vs_rk4_0.001', float('nan'))):.0f} % "
                     f"of RK4@0.001 s (paper: 62 %, i.e. the 38 % saving) while RK4@0.001 s "
                     f"stays at {_e(h.get('rk4_0.001_rmse_vs_flight'))} rad on the cost "
                     "scenario's sortie. ")
        num, eq = h.get("numerical_hybrid"), h.get("numerical_rk4_equal")
        if num and eq and eq["dt"] < num["dt"] and eq["wall_ms"] > num["wall_ms"]:
            text += (f"As a pure integration-error correction (trained on the fine-step "
                     f"reference) the hybrid at 0.005 s costs {num['wall_ms']:.3g} ms against "
                     f"{eq['wall_ms']:.3g} ms for the RK4 step of equal accuracy "
                     f"({eq['dt']:g} s), a {100 * h['numerical_speedup']:.0f} % saving. ")
        elif num:
            rk = eq or {}
            text += (f"As a pure integration-error correction (trained on the fine-step "
                     f"reference) the hybrid at 0.005 s ({num['wall_ms']:.3g} ms, pitch RMSE "
                     f"{_e(num['theta_rmse_vs_reference'])} rad against the reference) buys "
                     f"nothing: plain RK4 at {rk.get('dt', 0.005):g} s is as accurate for "
                     f"{_e(rk.get('wall_ms'))} ms, because RK4 at these steps is already "
                     f"accurate to ~1e-9 rad (SPEC section 8). ")
        parts.append(text)
    return ("Measured, not copied: " + " ".join(parts) +
            " Every number below was computed by this run; the paper's figures appear only in "
            "their own column.")


def _table1(af: dict) -> list[str]:
    lines = []
    for label, table in af["table1"].items():
        lines += [f"#### {label} ({len(table['sorties'])} test sorties)", "",
                  "| solver | one-step theta RMSE | 1 s theta RMSE | free-run theta RMSE | "
                  "free-run theta MAE | free-run theta max | free-run q RMSE | free-run u RMSE |",
                  "|---|---|---|---|---|---|---|---|"]
        for r in table["rows"]:
            fr = r.get("free_run", {})
            lines.append(
                f"| {r['solver']} | {_e(r.get('one_step', {}).get('theta_rmse'))} | "
                f"{_e(r.get('horizon_1s', {}).get('theta_rmse'))} | {_e(fr.get('theta_rmse'))} | "
                f"{_e(fr.get('theta_mae'))} | {_e(fr.get('theta_max'))} | "
                f"{_e(fr.get('q_rmse'))} | {_e(fr.get('u_rmse'))} |")
        for r in table["rows"]:
            for mode, why in r.get("missing", {}).items():
                lines.append(f"- {r['solver']}, {mode.replace('_', ' ')}: missing ({why})")
        lines.append("")
    lines += ["Paper (Table 1, its proposed framework vs its RK4 reference): RMSE 1.82e-3, "
              "MAE 1.47e-3, max 2.31e-3 rad.", ""]
    return lines


def _table2(af: dict) -> list[str]:
    lines = ["| weights | initial train loss | final train loss | initial val loss | best val "
             "loss | epochs | best epoch | monotonic (train/val) | stopped |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in af["table2"]:
        if "note" in r:
            lines.append(f"| {r['weights']} | {r['note']} | | | | | | | |")
            continue
        lines.append(f"| {r['weights']} | {_e(r['initial_train_loss'])} | "
                     f"{_e(r['final_train_loss'])} | {_e(r['initial_val_loss'])} | "
                     f"{_e(r['best_val_loss'])} | {r['epochs']} | {r['best_epoch']} | "
                     f"{r['monotonic_train']}/{r['monotonic_val']} | {r['stopped']} |")
    return lines + ["", "Losses are relative to the physics-only error (1 = no improvement).",
                    ""]


def _table3(af: dict) -> list[str]:
    t3 = af["table3"]
    lines = [f"Scenario: free run of test sortie `{t3['sortie']}` ({t3['duration_s']:.0f} s), "
             f"{t3['grid']}. Medians of repeats in one process.", "",
             "| solver | dt (s) | wall (ms) | ratio to hybrid@0.005 compiled | pitch RMSE vs "
             "flight | pitch RMSE vs reference |", "|---|---|---|---|---|---|"]
    for r in t3["rows"]:
        lines.append(f"| {r['solver']} | {_e(r['dt'])} | {r['wall_ms']:.3g} | "
                     f"{_e(r['ratio_to_hybrid_0.005'])} | {_e(r['theta_rmse_vs_flight'])} | "
                     f"{_e(r['theta_rmse_vs_reference'])} |")
    for r in t3.get("missing", []):
        lines.append(f"| {r['solver']} | {_e(r['dt'])} | missing: {r['missing']} | | | |")
    return lines + ["", "Paper (Table 3): RK4@0.001 s 148 ms, RK4@0.0005 s 287 ms, "
                        "hybrid@0.005 s 92 ms.", ""]


def _table4(af: dict) -> list[str]:
    lines = ["| scenario | solver | sorties | pitch-error growth (rad/s) | max error before "
             "divergence (rad) | diverged (error > 0.5 rad) | first divergence (s) |",
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
                     f"{_e(r['slope_rad_per_s'])} | {_e(r['max_error_rad'])} | "
                     f"{r['diverged']} of {r['sorties']} | {_e(r.get('first_divergence_s'))} |")
    return lines + [""]


def write_report(results: dict, path: Path) -> Path:
    """Write ``report.md`` (figures linked relative to the report)."""
    path = Path(path)
    lines = ["# uavdyn validation report", "", first_paragraph(results), ""]
    for af in results["airframes"]:
        ds = af["dataset"]
        lines += [f"## {af['airframe']} ({af['kind']})", "",
                  f"Dataset: {ds['sorties']} emulated sorties at {ds['sample_rate_hz']:g} Hz, "
                  f"{len(ds['test_sorties'])} held-out test sorties (split by sortie). Weights: "
                  + ", ".join(f"`{k}`: {Path(v).name if v else 'none'}"
                              for k, v in af["weights"].items()), "",
                  "### Table 1: accuracy (pitch in rad, q in rad/s, u in m/s)", "",
                  "One-step: one solver step from every recorded state; 1 s: restarted from the "
                  "recorded state every second; free run: whole sortie from its first state. "
                  "Solver steps below the 0.01 s log interval sub-step the logged "
                  "(zero-order-held) control; 0.02 s samples it at its own step.", ""]
        lines += _table1(af)
        lines += ["### Table 2: convergence", ""] + _table2(af)
        lines += ["### Table 3: cost", ""] + _table3(af)
        lines += ["### Table 4: robustness (free run, dt = 0.005 s)", ""] + _table4(af)
        lines += ["### Figures", ""]
        for name, fig in af.get("figures", {}).items():
            rel = os.path.relpath(fig, path.parent)
            lines += [f"![{name}]({rel})", ""]
    lines += [f"Total pipeline wall time: {results.get('wall_s', 0):.0f} s.", ""]
    path.write_text("\n".join(lines))
    return path
