"""How far beyond its training data the correction may act (issue 40): a knockout case's saved
correction re-scored on its test sorties with the envelope gate's fade replaced, the network
itself unchanged.

The gate (``uavdyn.learned.envelope``) is 1 inside the box of the training inputs and falls to
0 a fade width outside it; the fade was a quarter of each input's range before this round
(``SafeConfig.envelope_fade`` 0.25). For every case named, each test sortie's share of
samples outside the box and where the gate is below 1/2, then for each fade (``--fades``, in
range widths; 0: the file's own) the test sorties' 1 s pitch RMSE (``uavdyn evaluate``'s
horizon_1s, as the knockout scores it), the recovered share of the pooled error
``(err_a - err_corrected) / (err_a - err_b)`` (err_a, err_b: the knockout's own figures) and
the test sorties more than 2 % worse than (a). Prints JSON; ``--out`` also writes it.

Usage: ``python analysis/knockout_fade.py --knockout FILE --weights-dir W --cases f450/inflow
aerosonde/power [--fades 0,0.5,1] [--out FILE]`` (W: the run's ``--weights-dir``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np


def test_sorties(case: dict):
    """The knockout's test sorties (its split, balanced by condition, as it recorded)."""
    from uavdyn.flightdata import load_dataset

    data = case["dataset"]
    ds = load_dataset(data["folder"])
    moved = data["resplit"].get("moved (was, now)", {})
    for s in ds.sorties:
        if s.name in moved:
            s.meta["split"] = moved[s.name][1]
    return ds.test


def outside(net, airframe, sortie) -> tuple[float, float]:
    """Share of a sortie's samples outside the box, and with the gate below 1/2."""
    from uavdyn.experiments.tables import correction_structure, sortie_params
    from uavdyn.learned import hybrid_step
    from uavdyn.learned.formulations import network_inputs

    p = sortie_params(airframe, sortie.altitude_m)
    step = hybrid_step(net, airframe, compile=False)
    z = step.initial_state(sortie.states, sortie.controls, p,
                           float(np.median(np.diff(sortie.time))))
    layout = net.layout(correction_structure(airframe, net.kind, net.formulation))
    inp = network_inputs(layout, z, sortie.controls, p)[0]
    gate = np.asarray(net.envelope.gate(inp.T), float).ravel()
    return net.envelope.fraction_outside(inp), float(np.mean(gate < 0.5))


def rescored(net, airframe, sorties, nominal) -> list[float]:
    """Each sortie's 1 s pitch RMSE with the hybrid step of ``net``."""
    from uavdyn.learned import hybrid_step

    return model_errors(hybrid_step(net, airframe, compile=False), airframe, sorties, nominal)


def model_errors(model, airframe, sorties, nominal) -> list[float]:
    """Each sortie's 1 s pitch RMSE with the step ``model`` (a DiscreteModel) on the physics of
    ``airframe``, as the knockout scores it."""
    from uavdyn.evaluation import Solver, squared_error
    from uavdyn.experiments.predictions import Candidate, PredictionStore

    dt = float(np.median(np.diff(sorties[0].time)))
    cand = Candidate(Solver("corrected", model, dt), airframe, "identified", "knockout rescore")
    store = PredictionStore(nominal)
    out = []
    for s in sorties:
        sse, n = squared_error(*store.trajectory(cand, s)["horizon_1s"])
        out.append(math.sqrt(sse / n) if math.isfinite(sse) else math.inf)
    return out


WORSE = 1.02  # the knockout's "worse by more than 2 %"


def pooled_rmse(errors: list[float]) -> float:
    return math.sqrt(float(np.mean(np.square(errors))))


def knockout_references(case: dict, sorties) -> tuple[list, list, float, float | None]:
    """The knockout's own per-sortie 1 s errors of (a) and (b) on ``sorties`` and their pooled
    values (b: None where the case has no model with the term)."""
    recorded = {r["sortie"]: r for r in case["per_sortie"]}
    a = [recorded[s.name]["rmse_1s_a"] for s in sorties]
    b = [recorded[s.name].get("rmse_1s_b") for s in sorties]
    return a, b, pooled_rmse(a), None if None in b else pooled_rmse(b)


def rescore_summary(errors: list[float], a: list[float], pooled_a: float,
                    pooled_b: float | None) -> dict:
    """A re-scored correction's per-sortie 1 s ``errors`` against the knockout's (a) and (b):
    pooled error, recovered and removed shares, sorties worse than (a), each sortie's ratio."""
    pooled = pooled_rmse(errors)
    share = (None if pooled_b is None or pooled_a == pooled_b
             else (pooled_a - pooled) / (pooled_a - pooled_b))
    return {"rmse_1s_pooled": pooled, "recovered_share": share,
            "removed_share": (pooled_a - pooled) / pooled_a,
            "n_sorties_worse": int(sum(e > WORSE * x for e, x in zip(errors, a))),
            "ratio_to_a": [e / x for e, x in zip(errors, a)]}


def case_rows(case: dict, label: str, weights_dir: Path, fades: list[float]) -> dict:
    from uavdyn.airframes import load_airframe
    from uavdyn.learned import load_weights
    from uavdyn.learned.envelope import Envelope

    stem = weights_dir / label.replace("/", "_")
    airframe = load_airframe(stem.with_suffix(".toml"))
    net = load_weights(stem.with_suffix(".npz"), airframe)
    nominal = load_airframe(case["airframe"])
    sorties = test_sorties(case)
    a, b, pooled_a, pooled_b = knockout_references(case, sorties)
    sortie_rows = []
    for s, a_s, b_s in zip(sorties, a, b):
        out_box, low_gate = outside(net, airframe, s)
        sortie_rows.append({"sortie": s.name, "mission": s.mission,
                            "condition": s.meta.get("condition"),
                            "outside_box": out_box, "gate_below_half": low_gate,
                            "rmse_1s_a": a_s, "rmse_1s_b": b_s})
    runs = []
    for fade in fades:
        e = net.envelope
        width = np.maximum(e.high - e.low, 1e-9)
        env = e if fade <= 0 else Envelope(e.low, e.high, np.maximum(fade * width, 1e-9))
        errs = rescored(dataclasses.replace(net, envelope=env), airframe, sorties, nominal)
        runs.append({"fade": fade if fade > 0 else "file's own",
                     **rescore_summary(errs, a, pooled_a, pooled_b), "rmse_1s_corrected": errs})
    return {"weights": str(stem.with_suffix(".npz")),
            "file_fade_over_width": float(np.median(net.envelope.fade / np.maximum(
                net.envelope.high - net.envelope.low, 1e-12))),
            "err_a": pooled_a, "err_b": pooled_b, "sorties": sortie_rows, "fades": runs}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--knockout", required=True, help="knockout JSON with the cases")
    ap.add_argument("--weights-dir", required=True, type=Path,
                    help="the knockout run's --weights-dir (<airframe>_<term>.npz/.toml)")
    ap.add_argument("--cases", nargs="+", required=True, help="case keys, e.g. f450/inflow")
    ap.add_argument("--fades", default="0,0.5,1",
                    help="fade widths in range widths, comma-separated (0: the file's own)")
    ap.add_argument("--out", help="also write the JSON here")
    args = ap.parse_args()

    from uavdyn.evaluation.emit import emit_json, machine_facts

    cases = json.loads(Path(args.knockout).read_text())["cases"]
    fades = [float(f) for f in args.fades.split(",")]
    out = {"knockout": args.knockout, "cases": {
        label: case_rows(cases[label], label, args.weights_dir, fades) for label in args.cases},
        "machine": machine_facts(),
        "command": "python analysis/knockout_fade.py " + " ".join(sys.argv[1:])}
    emit_json(out, args.out)


if __name__ == "__main__":
    main()
