"""Would an ensemble of corrections learn the knocked-out term more reliably (issue 40's
candidate "a small ensemble")? The knockout cases' corrections of several training seeds,
scored on the case's test sorties one by one and as an ensemble: the mean of their hybrid
steps' next states (each seed's network with its own gate and bound on the same identified
physics), one step that costs as many networks as it has members.

For each case: the recovered share ``(err_a - err) / (err_a - err_b)`` of the pooled 1 s
pitch RMSE (err_a, err_b: the knockout's own figures), the test sorties more than 2 % worse
than (a) and every sortie's ratio to (a), per seed and for the ensemble. Prints JSON; ``--out``
also writes it.

Usage: ``python analysis/knockout_ensemble.py --knockout FILE --cases trainer2m/alpha_dot
... --weights-dirs W0 W1 W2 [--out FILE]`` (each W: a knockout run's ``--weights-dir``, one
per training seed, holding ``<airframe>_<term>.npz/.toml`` of the same identified model).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from knockout_fade import (  # the script's own folder is on the path
    knockout_references,
    model_errors,
    rescore_summary,
    test_sorties,
)


def ensemble_step(steps: list):
    """One DiscreteModel whose next state is the mean of the ``steps``' next states."""
    import casadi as ca

    from uavdyn.integrate import DiscreteModel

    first = steps[0]
    args = first.function.sx_in()
    mean = sum(s.function.call(args)[0] for s in steps) / len(steps)
    function = ca.Function("ensemble_step", args, [mean], first.function.name_in(),
                           first.function.name_out())
    return DiscreteModel(function, first.layout, dt=first.dt, strict=first.strict,
                         airframe=first.airframe,
                         description=f"mean of {len(steps)} hybrid steps")


def case_rows(case: dict, label: str, dirs: list[Path]) -> dict:
    from uavdyn.airframes import load_airframe
    from uavdyn.learned import hybrid_step, load_weights

    stem = label.replace("/", "_")
    airframe = load_airframe(dirs[0] / f"{stem}.toml")
    steps = [hybrid_step(load_weights(d / f"{stem}.npz", airframe), airframe, compile=False)
             for d in dirs]
    nominal = load_airframe(case["airframe"])
    sorties = test_sorties(case)
    a, _, pooled_a, pooled_b = knockout_references(case, sorties)
    members = [rescore_summary(model_errors(s, airframe, sorties, nominal), a, pooled_a,
                               pooled_b) for s in steps]
    mean = rescore_summary(model_errors(ensemble_step(steps), airframe, sorties, nominal), a,
                           pooled_a, pooled_b)
    return {"weights": [str(d / f"{stem}.npz") for d in dirs],
            "sorties": [s.name for s in sorties], "err_a": pooled_a, "err_b": pooled_b,
            "members": members, "ensemble": mean}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--knockout", required=True, help="knockout JSON with the cases")
    ap.add_argument("--cases", nargs="+", required=True, help="case keys, e.g. x500/inflow")
    ap.add_argument("--weights-dirs", nargs="+", required=True, type=Path,
                    help="one knockout --weights-dir per training seed")
    ap.add_argument("--out", help="also write the JSON here")
    args = ap.parse_args()

    from uavdyn.evaluation.emit import emit_json, machine_facts

    cases = json.loads(Path(args.knockout).read_text())["cases"]
    out = {"knockout": args.knockout, "cases": {
        label: case_rows(cases[label], label, args.weights_dirs) for label in args.cases},
        "machine": machine_facts(),
        "command": "python analysis/knockout_ensemble.py " + " ".join(sys.argv[1:])}
    emit_json(out, args.out)


if __name__ == "__main__":
    main()
