"""Where along a knockout case's test sortie does the corrected model go wrong, and had any
training flight been there? (issue 40: the test sorties a correction makes worse).

For each chosen sortie of one case of ``analysis/bench_knockout.py``: every model's one-step
pitch-acceleration error along the TRUE states (the emulator's noise-free record, the commands
as flown), ``(q_next_predicted - q_next_true) / dt`` for the model identified without the term
(a), with it (b) and the corrected one, averaged over windows of the sortie, beside the flight
condition of each window (airspeed, flight-path angle, commands). A one-step error of a model
held steady is its moment imbalance at that state: where the corrected model's grows while
(a)'s and (b)'s stay small, the network's output is wrong there. The same numbers for every
steady window of the training sorties (pitch rate and every command within a small band over
the window) show which steady flight conditions the correction was trained on. Per window
also the pitch acceleration the network puts out, split into its linear path and its hidden
layers (:func:`network_parts`, before the gate and the bound): which part carries it there.

A model can have the right moment along the flight and still predict it worse: per sortie
also each model's pitch damping ``d q_dot / d q`` at every true state, and the 1 s pitch
RMSE of each model and of the corrected one fed the TRUE pitch rate (``true_rate``,
:func:`rate_feedback`): where that is about (a)'s while the corrected model's is worse, the
loss is the network's feedback of the prediction's own pitch-rate error.

    python analysis/knockout_residuals.py --knockout docs/benchmarks/bench_knockout.json \
        --case trainer2m/alpha_dot --weights-dir W --out residuals.json

``W`` is the case's ``--weights-dir`` (the kept network and the identified airframe (a) it was
trained on); the model (b) is rebuilt from the case's recorded estimates. Prints a table and
writes JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import bench_knockout as knockout  # the sibling script (run as python analysis/...)
import numpy as np

from uavdyn import physics_step
from uavdyn.airframes.loader import load_airframe
from uavdyn.learned.formulations import network_inputs
from uavdyn.learned.hybrid import hybrid_step
from uavdyn.learned.mlp import mlp_forward
from uavdyn.learned.stability import map_pitch_damping
from uavdyn.learned.weights import CorrectionNet, load_weights
from uavdyn.model import NUMPY_OPS

STEADY_Q_BAND = 0.01        # rad/s: pitch rate spread over a steady window
STEADY_COMMAND_BAND = 0.01  # each command's spread over a steady window (its own units)


def one_step_errors(model, sortie) -> np.ndarray:
    """``(N-1,)`` one-step pitch-acceleration errors of ``model`` along the sortie's true
    states (its extra states started from the commands flown)."""
    body, controls = sortie.true_states, sortie.controls
    dt = float(sortie.dt)
    z = model.initial_state(body, controls, None, dt)
    return (model.step_rows(z[:-1], controls[:-1], model.p, dt)[:, 2] - body[1:, 2]) / dt


def network_parts(net: CorrectionNet, model, sortie) -> dict[str, np.ndarray]:
    """``(N-1,)`` the pitch acceleration (rad/s^2) the network of ``net`` puts out at each true
    state of the sortie (but the last), split into its linear path (``network_linear``) and
    its hidden layers with the output biases (``network_hidden``), before the gate and the
    bound, and the gate's value (``network_gate``, 1 without one). ``model`` is the corrected
    step (its state layout and parameters)."""
    body, controls = sortie.true_states[:-1], sortie.controls[:-1]
    z = model.initial_state(body, controls, None, float(sortie.dt))
    layout = net.layout(model.structure)
    inp, gains = network_inputs(layout, z, controls, model.p)
    x = inp.T

    def forward(skip) -> np.ndarray:  # the one MLP forward, with or without the linear path
        return np.asarray(mlp_forward(net.weights, net.biases, net.in_mean, net.in_scale,
                                      net.out_mean, net.out_scale, x, NUMPY_OPS,
                                      net.activation, skip=skip), float)

    hidden = forward(None)
    linear = forward(net.skip) - hidden if net.skip is not None else np.zeros_like(hidden)
    gate = (np.ones(len(z)) if layout.gate is None
            else np.broadcast_to(np.asarray(layout.gate(x, NUMPY_OPS), float).ravel(), len(z)))
    return {"network_linear": linear[2] * gains[:, 2],
            "network_hidden": hidden[2] * gains[:, 2],
            "network_gate": np.array(gate, float)}


def pitch_damping(model, sortie) -> np.ndarray:
    """``(N,)`` the model's pitch damping (1/s) at every true state of the sortie
    (:func:`uavdyn.learned.stability.map_pitch_damping`)."""
    body, controls = sortie.true_states, sortie.controls
    dt = float(sortie.dt)
    z = model.initial_state(body, controls, None, dt)
    return map_pitch_damping(model, z, controls, model.p, dt)


def rate_feedback(models: dict, sortie, horizon_s: float = 1.0) -> dict[str, float]:
    """Pitch RMSE of ``horizon_s`` windows restarted from the true states (as ``uavdyn
    evaluate``'s horizon_1s) for each model and for the corrected one with its network fed
    the TRUE pitch rate (``true_rate``): each step is (a)'s physics on the predicted state
    plus the network's part ``corrected(z~) - a(z~)`` at the predicted state ``z~`` with the
    true pitch rate. Where ``true_rate`` is about (a)'s and ``corrected`` worse, the loss is
    the network's feedback of the model's own pitch-rate error, not its output along the
    flight."""
    body, controls = sortie.true_states, sortie.controls
    dt = float(sortie.dt)
    n = int(round(horizon_s / dt))
    starts = np.arange(0, len(body) - n, n)
    phys, corr = models["a"], models["corrected"]
    n_phys = phys.initial_state(body[:2], controls[:2], None, dt).shape[1]

    def flown(model, true_rate: bool = False) -> float:
        z = np.array([model.initial_state(body[i:i + n + 1], controls[i:i + n + 1], None,
                                          dt)[0] for i in starts])
        sq = []
        for k in range(n):
            u = controls[starts + k]
            nxt = model.step_rows(z, u, model.p, dt)
            if true_rate:
                mixed = z.copy()
                mixed[:, 2] = body[starts + k, 2]
                nxt[:, :n_phys] = (phys.step_rows(z[:, :n_phys], u, phys.p, dt)
                                   + model.step_rows(mixed, u, model.p, dt)[:, :n_phys]
                                   - phys.step_rows(mixed[:, :n_phys], u, phys.p, dt))
            z = nxt
            sq.append((z[:, 3] - body[starts + k + 1, 3]) ** 2)
        return float(np.sqrt(np.mean(sq)))

    return {**{k: flown(m) for k, m in models.items()}, "true_rate": flown(corr, True)}


def windows(sortie, errors: dict[str, np.ndarray], width_s: float) -> list[dict]:
    """Per window of ``width_s``: the mean and RMS of each series of ``errors`` (the models'
    one-step errors, the network's parts), the flight condition, and whether the window is
    steady."""
    body, controls = sortie.true_states[1:], sortie.controls[1:]
    t = sortie.time[1:] - sortie.time[0]
    speed = np.hypot(body[:, 0], body[:, 1])
    gamma = body[:, 3] - np.arctan2(body[:, 1], body[:, 0])
    out = []
    for start in np.arange(0.0, t[-1] - 0.5 * width_s, width_s):
        sel = (t >= start) & (t < start + width_s)
        if not np.any(sel):
            continue
        steady = (np.ptp(body[sel, 2]) < STEADY_Q_BAND
                  and all(np.ptp(controls[sel, j]) < STEADY_COMMAND_BAND
                          for j in range(controls.shape[1])))
        out.append({"start_s": float(start), "steady": bool(steady),
                    "airspeed_mps": float(speed[sel].mean()),
                    "gamma_deg": float(np.degrees(gamma[sel].mean())),
                    "commands": [float(c) for c in controls[sel].mean(axis=0)],
                    **{f"mean_{k}": float(e[sel].mean()) for k, e in errors.items()},
                    **{f"rms_{k}": float(np.sqrt(np.mean(e[sel] ** 2)))
                       for k, e in errors.items()}})
    return out


def correction_of(case: dict, weights_dir: Path) -> tuple[CorrectionNet, object]:
    """The case's kept network and the identified airframe (a) it was trained on."""
    stem = case["airframe_name"] + "_" + case["term"]
    af_a = load_airframe(weights_dir / f"{stem}.toml")
    return load_weights(weights_dir / f"{stem}.npz", af_a), af_a


def models_of(case: dict, net: CorrectionNet, af_a) -> dict:
    """The case's three steps: (a) and its kept correction ``net`` (:func:`correction_of`),
    (b) from the nominal airframe with the recorded estimates of the fit with the term."""
    nominal = load_airframe(knockout.airframe_ref(case["airframe"])[0])
    est = case["identify"]["with"]["estimates"]
    af_b = nominal.replace(**{name: e["value"] for name, e in est.items()})
    return {"a": physics_step(af_a), "b": physics_step(af_b),
            "corrected": hybrid_step(net, af_a)}


def worse_sorties(case: dict) -> list[str]:
    """The test sorties the correction made more than 2 % worse than (a)."""
    return [r["sortie"] for r in case.get("per_sortie", [])
            if r["rmse_1s_corrected"] > 1.02 * r["rmse_1s_a"]]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--knockout", required=True, type=Path, help="bench_knockout JSON")
    ap.add_argument("--case", required=True, help="case label, e.g. trainer2m/alpha_dot")
    ap.add_argument("--weights-dir", required=True, type=Path,
                    help="the case's --weights-dir (network and identified airframe (a))")
    ap.add_argument("--sorties", nargs="+", default=None,
                    help="test sorties to show (default: those made worse by > 2 %%)")
    ap.add_argument("--window", type=float, default=3.0, help="window length in s")
    ap.add_argument("--out", type=Path, default=None, help="result JSON")
    args = ap.parse_args(argv)
    doc = json.loads(args.knockout.read_text())
    case = doc["cases"].get(args.case)
    if case is None or case.get("status") != "done":
        print(f"error: {args.knockout}: no finished case '{args.case}'", file=sys.stderr)
        return 2
    if not case["correction"].get("kept"):
        print(f"error: {args.case}: no correction kept, nothing to show", file=sys.stderr)
        return 2
    ds = knockout.load_dataset(case["dataset"]["folder"])
    if case["dataset"]["resplit"]["balance_conditions"]:
        knockout.deal_conditions_by_mission(ds)
    net, af_a = correction_of(case, args.weights_dir)
    models = models_of(case, net, af_a)
    by_name = {s.name: s for s in ds.sorties}
    chosen = args.sorties or worse_sorties(case)
    command = ["python analysis/knockout_residuals.py"] + list(argv or sys.argv[1:])
    result = {"command": " ".join(command),
              "case": args.case, "window_s": args.window, "sorties": {}, "train_steady": []}
    for name in chosen:
        sortie = by_name[name]
        errors = {k: one_step_errors(m, sortie) for k, m in models.items()}
        damping = {k: pitch_damping(m, sortie) for k, m in models.items()}
        result["sorties"][name] = {
            "mission": sortie.mission, "condition": sortie.meta.get("condition"),
            "rms": {k: float(np.sqrt(np.mean(e ** 2))) for k, e in errors.items()},
            "pitch_damping": {k: {"percentiles": dict(zip(("0", "5", "50", "95", "100"),
                                                          np.percentile(d, [0, 5, 50, 95, 100]
                                                                        ).tolist())),
                                  "share_positive": float(np.mean(d > 0))}
                              for k, d in damping.items()},
            "rmse_1s_rate_feedback": rate_feedback(models, sortie),
            "windows": windows(sortie, errors | network_parts(net, models["corrected"], sortie),
                               args.window)}
    for sortie in ds.split("train"):
        errors = {k: one_step_errors(m, sortie) for k, m in models.items()}
        series = errors | network_parts(net, models["corrected"], sortie)
        result["train_steady"] += [{"sortie": sortie.name, **w}
                                   for w in windows(sortie, series, args.window) if w["steady"]]
    result["train_steady_range"] = steady_range(result["train_steady"])
    print_table(result)
    if args.out:
        knockout.write_atomic(args.out, json.dumps(knockout.json_safe(result), indent=1))
    return 0


def steady_range(rows: list[dict]) -> dict:
    """The least and greatest airspeed, flight-path angle and each command over the steady
    training windows (None where there are none)."""
    if not rows:
        return {"airspeed_mps": None, "gamma_deg": None, "commands": None}
    cmds = np.array([r["commands"] for r in rows])
    return {key: [min(r[key] for r in rows), max(r[key] for r in rows)]
            for key in ("airspeed_mps", "gamma_deg")} | {
        "commands": [[float(c.min()), float(c.max())] for c in cmds.T]}


def print_table(result: dict) -> None:
    """The windows as text: one row each, the models' mean one-step errors in rad/s^2."""
    def row(label: str, w: dict) -> str:
        cmds = " ".join(f"{c:+.3f}" for c in w["commands"])
        return (f"{label:16s} V {w['airspeed_mps']:5.2f} gamma {w['gamma_deg']:+5.1f} "
                f"cmd {cmds}  a {w['mean_a']:+.3f}  b {w['mean_b']:+.3f}  "
                f"corrected {w['mean_corrected']:+.3f}  network linear "
                f"{w['mean_network_linear']:+.3f} hidden {w['mean_network_hidden']:+.3f}"
                f"{'  steady' if w['steady'] else ''}")
    for name, s in result["sorties"].items():
        print(f"{name} ({s['mission']}, {s['condition']}): mean one-step pitch-acceleration "
              "error per window (rad/s^2); RMS over the sortie "
              + ", ".join(f"{k} {v:.4f}" for k, v in s["rms"].items()))
        print("  1 s pitch RMSE (mrad): " + ", ".join(
            f"{k} {1000 * v:.2f}" for k, v in s["rmse_1s_rate_feedback"].items())
            + "; pitch damping (1/s) median, largest, share positive: " + "; ".join(
            f"{k} {d['percentiles']['50']:+.2f}, {d['percentiles']['100']:+.2f}, "
            f"{100 * d['share_positive']:.0f} %" for k, d in s["pitch_damping"].items()))
        for w in s["windows"]:
            print(row(f"  {w['start_s']:4.0f} s", w))
    span = result["train_steady_range"]
    print("steady windows of the training sorties"
          + (f" (gamma {span['gamma_deg'][0]:+.1f} to {span['gamma_deg'][1]:+.1f} deg):"
             if span["gamma_deg"] else ": none"))
    for w in result["train_steady"]:
        print(row(f"  {w['sortie']} {w['start_s']:.0f}", w))


if __name__ == "__main__":
    sys.exit(main())
