"""Why a correction can pass validation and lose calm test sorties: the noise of the state a
window starts from (issue 40).

For one knockout case whose correction was saved (``bench_knockout.py --weights-dir``), every
sortie of a split is cut into 1 s windows every 0.5 s and flown by the identified physics (a)
and the hybrid step (corrected) three ways:

* ``truth``: started from the noise-free state, scored against the noise-free pitch (what the
  knockout table scores);
* ``records_vs_truth``: started from the recorded (noisy) state, scored against the truth;
* ``records``: started from the record, scored against the records (what training and
  validation see);
* ``fitted``: started from the state each model fits to the window's first records over
  ``--fit-s`` (``SafeConfig.start_fit_s``), scored against the records.

A correction that damps the start's noise out scores better in the last two and worse in the
first. Prints JSON (pitch RMSE in mrad per sortie and model); ``--out`` also writes it.

Usage: ``python analysis/start_noise.py --knockout FILE --case aerosonde/alpha_dot
--weights W.npz --airframe W.toml [--split validation] [--out FILE]``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

HORIZON_S, STRIDE_S = 1.0, 0.5


def window_rmse(model, sortie, starts: np.ndarray, target: np.ndarray, p: np.ndarray,
                dt: float) -> float:
    """Pitch RMSE (mrad) of 1 s windows every 0.5 s started from ``starts``."""
    step = model.function
    horizon, stride = round(HORIZON_S / dt), round(STRIDE_S / dt)
    sq = []
    for k0 in range(0, len(sortie.time) - horizon, stride):
        z = np.asarray(model.initial_state(starts[k0, :4], sortie.controls[k0], p, dt),
                       float).ravel()
        for k in range(k0, k0 + horizon):
            z = np.asarray(step(z, sortie.controls[k], p, dt), float).ravel()
            sq.append((z[3] - target[k + 1, 3]) ** 2)
    return 1e3 * math.sqrt(float(np.mean(sq)))


def fitted_starts(model, sortie, p: np.ndarray, dt: float, span: int) -> np.ndarray:
    """The records with each window's start replaced by the state ``model`` fits to the
    window's first ``span`` records (``SafeConfig.start_fit_s``; the record where the model
    does not explain them within the noise)."""
    from uavdyn.integrate.start_fit import fit_starts, start_fit_function
    from uavdyn.learned.rules import state_noise

    horizon, stride = round(HORIZON_S / dt), round(STRIDE_S / dt)
    ks = np.arange(0, len(sortie.time) - horizon, stride)
    z0 = np.array([np.asarray(model.initial_state(sortie.states[k, :4], sortie.controls[k],
                                                  p, dt), float).ravel() for k in ks])
    u = np.array([sortie.controls[k:k + span - 1] for k in ks])
    y = np.array([sortie.states[k + 1:k + span, :4] for k in ks])
    fits = fit_starts(start_fit_function(model.function, span), z0, u, y,
                      np.repeat(p[:, None], len(ks), axis=1), dt,
                      np.tile(state_noise(sortie), (len(ks), 1)), span)
    out = np.array(sortie.states, float, copy=True)
    out[ks, :4] = fits.body
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--knockout", required=True, help="knockout JSON with the case")
    ap.add_argument("--case", required=True, help="case key, e.g. aerosonde/alpha_dot")
    ap.add_argument("--weights", required=True, help="the case's saved correction (.npz)")
    ap.add_argument("--airframe", required=True, help="the identified airframe it sits on")
    ap.add_argument("--split", default="validation", choices=("train", "validation", "test"))
    ap.add_argument("--fit-s", type=float, default=0.2,
                    help="span of the fitted starts (s; default 0.2)")
    ap.add_argument("--out", help="also write the JSON here")
    args = ap.parse_args()

    from uavdyn.airframes import load_airframe
    from uavdyn.evaluation.emit import emit_json, machine_facts
    from uavdyn.flightdata import load_dataset
    from uavdyn.integrate import physics_step
    from uavdyn.learned import hybrid_step, load_weights

    case = json.loads(Path(args.knockout).read_text())["cases"][args.case]
    data = case["dataset"]
    ds = load_dataset(data["folder"])
    moved = data["resplit"].get("moved (was, now)", {})
    for s in ds.sorties:  # the knockout's own split (balanced by condition)
        if s.name in moved:
            s.meta["split"] = moved[s.name][1]
    airframe = load_airframe(args.airframe)
    net = load_weights(args.weights, airframe)
    models = {"a": physics_step(airframe), "corrected": hybrid_step(net, airframe,
                                                                    compile=False)}
    p = np.asarray(airframe.p, float)
    span = round(args.fit_s / float(np.median(np.diff(ds.sorties[0].time)))) + 1
    rows = []
    for s in ds.sorties:
        if s.meta.get("split") != args.split or s.true_states is None:
            continue
        dt = float(np.median(np.diff(s.time)))
        row = {"sortie": s.name, "mission": s.mission, "condition": s.meta.get("condition")}
        for label, model in models.items():
            row[label] = {
                "truth": window_rmse(model, s, s.true_states, s.true_states, p, dt),
                "records_vs_truth": window_rmse(model, s, s.states, s.true_states, p, dt),
                "records": window_rmse(model, s, s.states, s.states, p, dt),
                "fitted": window_rmse(model, s, fitted_starts(model, s, p, dt, span),
                                      s.states, p, dt)}
        rows.append(row)
    out = {"knockout": args.knockout, "case": args.case, "weights": args.weights,
           "split": args.split, "horizon_s": HORIZON_S, "stride_s": STRIDE_S,
           "fit_span_s": args.fit_s,
           "unit": "mrad", "sorties": rows,
           "machine": machine_facts(),
           "command": "python analysis/start_noise.py " + " ".join(sys.argv[1:])}
    emit_json(out, args.out)


if __name__ == "__main__":
    main()
