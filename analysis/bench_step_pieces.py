"""What the hybrid step's extra cost is made of (issue 40: "the hybrid step within 1.5x the
physics step"), one piece at a time, in the C loop of ``analysis/bench_rollout.py``.

Variants of the same ``improved`` step on the airframe's physics, each adding one piece of the
safe correction: ``const`` (a constant residual: the cost of adding anything), ``linear`` (the
network's inputs computed inside the step and one linear map of them), ``+bound`` (the output
clamp), ``+gate`` (the envelope gate), ``+bound+gate`` (all the guard; no hidden layer), then
the weight file's own network (``real``). The linear map's weights are random and tiny (1e-3),
so the state stays at the trim and the timing does not depend on them. Each variant is timed
``--rounds`` times, all variants compiled into one program and run in turn, pass after pass
(the load moves all alike); the minimum and the median per sample are printed as JSON, with
the ratio of each median to the physics'. ``--dataset`` times them on recorded flight instead
of at the trim (:func:`uavdyn.evaluation.c_loop.recorded_workload`; an exact hover flatters the
physics).

Usage: ``python analysis/bench_step_pieces.py --airframe examples/x500.toml --weights W.npz
--airspeed 0 [--dataset DIR] [--out FILE]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys

import casadi as ca
import numpy as np

from uavdyn.evaluation.c_loop import CLoop, LoopWork, recorded_workload
from uavdyn.evaluation.emit import emit_json, machine_facts


def variants(airframe, net, shapes: list[tuple[int, ...]]) -> dict[str, ca.Function]:
    """The step variants, named (see the module docstring); ``shapes``: the hidden widths of
    the random networks (with a linear path and the whole guard) timed beside them."""
    from uavdyn.integrate import physics_step
    from uavdyn.learned.formulations import improved_step
    from uavdyn.learned.mlp import folded_forward
    from uavdyn.model import CASADI_OPS, make_rhs, structure_of

    structure = structure_of(airframe)
    layout = net.layout(structure)
    rhs = make_rhs(structure)

    def build(lay, network) -> ca.Function:
        z, u = ca.SX.sym("z", lay.n_state), ca.SX.sym("u", structure.nu)
        p, dt = ca.SX.sym("p", structure.np), ca.SX.sym("dt")
        return ca.Function("step", [z, u, p, dt],
                           [improved_step(lay, rhs, z, u, p, dt, network, CASADI_OPS)])

    rng = np.random.default_rng(0)
    weights = [rng.normal(size=(3, layout.n_inputs)) * 1e-3]
    biases = [rng.normal(size=3) * 1e-3]

    def linear(inp):
        return folded_forward(weights, biases, inp, CASADI_OPS, None)

    def const(inp):
        return ca.DM([1e-3, 0.0, 0.0]) + 0.0 * inp[0]

    def random_network(hidden: tuple[int, ...]):
        sizes = [layout.n_inputs, *hidden, 3]
        ws = [rng.normal(size=(b, a)) * 1e-3 for a, b in zip(sizes[:-1], sizes[1:])]
        bs = [rng.normal(size=b) * 1e-3 for b in sizes[1:]]
        skip = rng.normal(size=(3, layout.n_inputs)) * 1e-3
        return lambda inp: folded_forward(ws, bs, inp, CASADI_OPS, skip)

    bare = dataclasses.replace(layout, gate=None, bound=None)
    out = {"physics": physics_step(airframe).function,
           "const": build(bare, const),
           "linear": build(bare, linear),
           "linear+bound": build(dataclasses.replace(layout, gate=None), linear),
           "linear+gate": build(dataclasses.replace(layout, bound=None), linear),
           "linear+bound+gate": build(layout, linear)}
    for hidden in shapes:
        name = f"random {layout.n_inputs}-{'-'.join(map(str, (*hidden, 3)))} + linear path"
        out[name] = build(layout, random_network(hidden))
    out["real"] = build(layout, net.casadi)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--airframe", required=True, help="airframe file the weights sit on")
    ap.add_argument("--weights", required=True, help="correction weight file")
    ap.add_argument("--airspeed", type=float, required=True, help="trim airspeed in m/s")
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--shapes", default="4,4,4;8;",
                    help="hidden widths of random networks to time, ';' between networks, "
                         "',' between layers, empty: no hidden layer (default '4,4,4;8;')")
    ap.add_argument("--dataset", help="time on recorded flight: back-to-back 1 s windows of "
                    "this dataset's test sorties from their records under the recorded "
                    "commands (default: one chain at the trim, the trim command held)")
    ap.add_argument("--out", help="also write the JSON here")
    args = ap.parse_args()
    shapes = [tuple(int(w) for w in item.split(",") if w.strip())
              for item in args.shapes.split(";")]

    from uavdyn.airframes import load_airframe
    from uavdyn.integrate import physics_step
    from uavdyn.learned import hybrid_step, load_weights
    from uavdyn.linear import trim

    airframe = load_airframe(args.airframe)
    net = load_weights(args.weights, airframe)
    point = trim(airframe, args.airspeed)
    p = np.asarray(airframe.p, float)
    models = (physics_step(airframe), hybrid_step(net, airframe, compile=False))
    if args.dataset:  # recorded flight: windows of the test sorties from their records
        from uavdyn.flightdata import load_dataset
        flights = load_dataset(args.dataset).split("test")
        work = {m.function.size1_in(0): recorded_workload(m, flights, 1.0, p) for m in models}
        loop_args = {nx: (w.starts, w.controls, flights[0].dt, w.steps)
                     for nx, w in work.items()}
    else:  # one chain at the trim under the held trim command
        loop_args = {m.function.size1_in(0): (np.asarray(
            m.initial_state(point.x, point.u, p, 0.01), float).ravel(), point.u, 0.01,
            args.samples) for m in models}
    steps = variants(airframe, net, shapes)
    works = []
    for fn in steps.values():
        starts, controls, dt, n = loop_args[fn.size1_in(0)]
        works.append(LoopWork(fn, starts, controls, p, dt, n))
    with CLoop(works) as loop:  # all variants in one program, in turn, pass after pass
        run = loop.run(args.rounds)
    times = {name: list(run.pass_us[:, i]) for i, name in enumerate(steps)}
    physics = statistics.median(times["physics"])
    results = {}
    for name, fn in steps.items():
        expanded = fn if fn.is_a("SXFunction") else fn.expand()
        med = statistics.median(times[name])
        results[name] = {"us_per_sample_median": med, "us_per_sample_min": min(times[name]),
                         "over_physics": med / physics,
                         "instructions": expanded.n_instructions()}
    out = {"airframe": args.airframe, "weights": args.weights, "network": net.describe(),
           "samples": args.samples, "rounds": args.rounds, "results": results,
           "machine": machine_facts(),
           "command": "python analysis/bench_step_pieces.py " + " ".join(sys.argv[1:])}
    emit_json(out, args.out)


if __name__ == "__main__":
    main()
