"""What ``uavdyn design-input`` writes: the schedule CSV, ArduPilot SYSID-mode parameters where
the vehicle has that mode, and the design report (JSON and Markdown)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from uavdyn.excitation.design import ExcitationDesign
from uavdyn.identify.prediction import PredictedErrors

SID_AXIS_MIXER_PITCH = 11   # ArduCopter SID_AXIS 11: "Mixer Pitch"
SID_FADE_S = 2.0            # SID_T_FADE_IN / SID_T_FADE_OUT (ArduPilot's defaults)


def schedule_csv(design: ExcitationDesign) -> str:
    """The schedule as CSV: ``time_s``, the two controls' increments about trim and
    ``autopilot`` (1 on, 0 hands-off), under ``#`` lines saying units and about what."""
    c0, c1 = design.controls
    units = {"elevator": "rad, the airframe file's sign convention", "throttle": "0..1",
             "collective": "0..1", "pitch_cmd": "-1..1, nose up positive"}
    trims = ", ".join(f"{c} = {v:.6g}" for c, v in zip(design.controls, design.trim_controls))
    lines = [f"# uavdyn design-input: {design.signal} on {design.controls[design.channel]} for "
             f"'{design.airframe}' ({design.kind}), one sortie of {design.duration_s:g} s",
             f"# increments about the trim at {design.speed:g} m/s: {trims}",
             f"# units: time_s s; {c0}_delta {units[c0]}; {c1}_delta {units[c1]}",
             "# autopilot: 1 = attitude/speed loops on, 0 = hands-off (open loop: fly the "
             "increments on the trim controls)",
             f"# timing: {design.rule}; amplitude {design.amplitude:.5g} "
             f"({design.amplitude_why})",
             f"time_s,{c0}_delta,{c1}_delta,autopilot"]
    for t, u, h in zip(design.time, design.increments, design.hands_off):
        lines.append(f"{t:.4f},{u[0]:.6g},{u[1]:.6g},{0 if h else 1}")
    return "\n".join(lines) + "\n"


def ardupilot_params(design: ExcitationDesign) -> tuple[str | None, str]:
    """ArduPilot SYSID-mode parameters for the design's band (None where the vehicle has no
    such mode) and what they cannot express."""
    if design.kind != "multirotor":
        return None, ("ArduPilot's SYSTEMID mode is a multicopter (and QuadPlane VTOL) mode: "
                      "a conventional fixed wing has none. Fly schedule.csv (pilot or a "
                      "scripted RC override), hands-off where its autopilot column is 0.")
    rec = max(design.duration_s - 2 * SID_FADE_S, 1.0)
    text = "\n".join([
        f"# uavdyn design-input for '{design.airframe}': SYSTEMID mode (Copter mode 25)",
        "# a chirp injected at the mixer's pitch output over the designed band; "
        "SID_MAGNITUDE in mixer units",
        f"SID_AXIS,{SID_AXIS_MIXER_PITCH}",
        f"SID_MAGNITUDE,{design.amplitude:.4g}",
        f"SID_F_START_HZ,{design.band_hz[0]:.4g}",
        f"SID_F_STOP_HZ,{design.band_hz[1]:.4g}",
        f"SID_T_FADE_IN,{SID_FADE_S:g}",
        f"SID_T_REC,{rec:g}",
        f"SID_T_FADE_OUT,{SID_FADE_S:g}"]) + "\n"
    why = ("SYSTEMID flies a chirp only: the 3-2-1-1, doublets and multisine of schedule.csv "
           "cannot be expressed in it, and its mixer-pitch units are ArduPilot's (-1..1 of "
           "its own pitch mix), not necessarily this file's pitch_cmd scale; the chirp "
           f"sweeps {design.band_hz[0]:.3g}..{design.band_hz[1]:.3g} Hz over "
           f"{rec:g} s with the attitude loop on")
    return text, why


def report(design: ExcitationDesign, predicted: PredictedErrors | None, sorties: int,
           ardupilot_note: str, refused: list[str] | None = None) -> tuple[dict, str]:
    """The design report as JSON data and as Markdown (``refused``: what identify's
    excitation screen would refuse on the calm emulated sorties)."""
    data = {**design.summary(), "ardupilot": ardupilot_note, "predicted": None,
            "identify_screen_on_calm_sorties": list(refused or [])}
    md = [f"# Flight-test input for {design.airframe}", "",
          f"- signal: {design.signal} on {design.controls[design.channel]}, one sortie of "
          f"{design.duration_s:g} s at {design.speed:g} m/s",
          f"- timed from: {design.mode.name}, {design.mode.natural_frequency:.4g} rad/s "
          f"({design.mode.natural_frequency / (2 * math.pi):.3g} Hz), damping "
          f"{design.mode.damping:.3g} ({design.mode.source})",
          f"- timing: {design.rule}",
          f"- amplitude: {design.amplitude:.5g} ({design.amplitude_why})",
          "- inputs: " + "; ".join(f"{e['signal']} at {e['t_s']:g} s" for e in design.events)]
    if design.peak_factor() is not None:
        md.append(f"- relative peak factor: {design.peak_factor():.3f} (1 = a single sine)")
    md += [f"- ArduPilot: {ardupilot_note}", *[f"- note: {n}" for n in design.notes]]
    md += [f"- warning: on the calm emulated sorties `uavdyn identify` would refuse {r}"
           for r in refused or []]
    if predicted is not None:
        rows = [{"name": n, "nominal": float(v), "predicted_std_error": float(s),
                 "ratio": float(r)}
                for n, v, s, r in zip(predicted.names, predicted.nominal, predicted.std_error,
                                      predicted.ratio())]
        data["predicted"] = {"sorties": sorties, "windows": predicted.windows,
                             "window_s": predicted.window_s, "parameters": rows,
                             "collinear_groups": predicted.collinear_groups,
                             "kind": "Cramer-Rao lower bound"}
        md += ["", f"## Predicted standard errors ({sorties} sorties, {predicted.windows} "
               f"windows of {predicted.window_s:g} s)", "",
               "Cramer-Rao bound of the output-error fit at the file's values on the emulated "
               "flights with the emulator's sensor noise. A **lower bound**: turbulence and "
               "model error colour the residuals, and the corrected standard errors "
               "`uavdyn identify` reports on real data are larger. It scales like "
               "1/sqrt(sorties).", "",
               "| parameter | file value | predicted SE | abs(value) / SE |", "|---|---|---|---|"]
        md += [f"| {r['name']} | {r['nominal']:.4g} | {r['predicted_std_error']:.3g} | "
               + (f"{r['ratio']:.3g} |" if r["nominal"] else
                  f"(file value 0: resolved if abs(value) > {3 * r['predicted_std_error']:.3g}) |")
               for r in rows]
        if predicted.collinear_groups:
            md.append(f"\nCollinear (not separable by this flight): "
                      f"{predicted.collinear_groups}")
    return data, "\n".join(md) + "\n"


def write_design(folder: Path, design: ExcitationDesign, predicted: PredictedErrors | None,
                 sorties: int, refused: list[str] | None = None) -> list[str]:
    """Write ``schedule.csv``, ``ardupilot_sysid.param`` (where it applies), ``design.json``
    and ``design.md`` into ``folder``; returns the names written."""
    (folder / "schedule.csv").write_text(schedule_csv(design))
    written = ["schedule.csv"]
    params, note = ardupilot_params(design)
    if params is not None:
        (folder / "ardupilot_sysid.param").write_text(params)
        written.append("ardupilot_sysid.param")
    data, md = report(design, predicted, sorties, note, refused)
    (folder / "design.json").write_text(json.dumps(data, indent=2, default=_plain) + "\n")
    (folder / "design.md").write_text(md)
    return written + ["design.json", "design.md"]


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(type(value).__name__)
