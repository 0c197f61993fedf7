"""Benchmark of the integrators on the fixed-wing model: cost per RK4 step (compiled C, CasADi
VM, plain NumPy) and wall time of adaptive solvers (scipy RK45/DOP853, CVODES) over the same
10 s sortie at matched pitch accuracy. Prints JSON.

All solvers see the same zero-order-held input (elevator doublet + chirp on a 0.005 s grid);
adaptive solvers are restarted at every input change, as they must be for a ZOH input.
Usage: ``python analysis/bench_integrators.py [--repeats 5] [--out FILE]``.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import sys
import time

import numpy as np
import scipy.integrate

from uavdyn.airframes import load_airframe
from uavdyn.integrate import (
    compile_function,
    reference_step,
    rk4_numpy,
    rk4_step,
    rollout,
    simulate,
)
from uavdyn.integrate.inputs import chirp, doublet
from uavdyn.linear import trim
from uavdyn.model import build_model, numpy_rhs

DT = 0.005
DURATION = 10.0


def sortie_controls(u_trim: np.ndarray, n: int) -> np.ndarray:
    t = np.arange(n) * DT
    u = np.tile(u_trim, (n, 1))
    u[:, 0] += doublet(t, math.radians(2.0), start=0.5, width=0.5)
    u[:, 0] += chirp(t, math.radians(1.0), start=2.0, duration=7.0, f0=0.1, f1=2.0)
    return u


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def pitch_rmse(traj: np.ndarray, ref: np.ndarray) -> float:
    return float(np.sqrt(np.mean((traj[:, 3] - ref[:, 3]) ** 2)))


def solve_ivp_piecewise(rhs, x0, U, p, method: str, rtol: float) -> np.ndarray:
    """Adaptive scipy solver restarted on every control interval (the input is ZOH)."""
    out = np.empty((len(U) + 1, len(x0)))
    x = out[0] = x0
    for k, u in enumerate(U):
        sol = scipy.integrate.solve_ivp(lambda t, y, u=u: rhs(y, u, p), (0.0, DT), x,
                                        method=method, rtol=rtol, atol=rtol * 1e-2)
        x = out[k + 1] = sol.y[:, -1]
    return out


def matched(name: str, run, target: float, tolerances, repeats: int) -> dict:
    """Loosest tolerance whose pitch RMSE reaches ``target``; its median wall time."""
    tried = []
    for tol in tolerances:
        traj, err = run(tol)
        tried.append({"tol": tol, "pitch_rmse_rad": err})
        if err <= target:
            wall = median_time(lambda tol=tol: run(tol), repeats)
            return {"solver": name, "tol": tol, "pitch_rmse_rad": err, "wall_s": wall,
                    "tried": tried}
    return {"solver": name, "tol": None, "pitch_rmse_rad": tried[-1]["pitch_rmse_rad"],
            "wall_s": None, "tried": tried, "note": "target accuracy not reached"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default=None, help="also write the JSON here")
    args = parser.parse_args()

    af = load_airframe("aerosonde")
    point = trim(af, 25.0)
    model = build_model(af)
    n = int(round(DURATION / DT))
    U = sortie_controls(point.u, n)
    step = rk4_step(model.f)
    fine = 64
    ref = simulate(step, point.x, np.repeat(U, fine, axis=0), af.p, DT / fine)[::fine]

    vm_roll = rollout(step, n)
    t0 = time.perf_counter()
    c_roll = compile_function(vm_roll)
    compile_s = time.perf_counter() - t0
    x0, UT = point.x, U.T

    def run_c():
        return np.array(c_roll(x0, UT, af.p, DT))

    def run_vm():
        return np.array(vm_roll(x0, UT, af.p, DT))

    rhs = numpy_rhs(af.kind)
    c_s = median_time(run_c, max(args.repeats, 20))
    vm_s = median_time(run_vm, args.repeats)
    np_s = median_time(lambda: rk4_numpy(rhs, x0, U, af.p, DT), max(1, args.repeats // 2))
    rk4_traj = np.vstack([x0, run_c().T])
    target = pitch_rmse(rk4_traj, ref)

    # long rollout: per-step cost without call overhead
    n_long = 100_000
    long_roll = compile_function(rollout(step, n_long))
    U_long = np.tile(point.u[:, None], (1, n_long))
    long_s = median_time(lambda: long_roll(x0, U_long, af.p, 0.001), 3)

    def scipy_run(method):
        def run(tol):
            traj = solve_ivp_piecewise(rhs, x0, U, af.p, method, tol)
            return traj, pitch_rmse(traj, ref)
        return run

    cv_fns = {}

    def cvodes_run(tol):
        if tol not in cv_fns:
            cv_fns[tol] = rollout(reference_step(model.f, tol=tol), n)
        traj = np.vstack([x0, np.array(cv_fns[tol](x0, UT, af.p, DT)).T])
        return traj, pitch_rmse(traj, ref)

    tols = [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12]
    adaptive = [
        matched("scipy RK45", scipy_run("RK45"), target, tols, 1),
        matched("scipy DOP853", scipy_run("DOP853"), target, tols, 1),
        matched("CVODES", cvodes_run, target, tols, 3),
    ]
    result = {
        "machine": {"python": sys.version.split()[0], "platform": platform.platform(),
                    "cores": __import__("os").cpu_count()},
        "scenario": f"aerosonde trimmed at 25 m/s, elevator doublet + chirp, {DURATION:g} s, "
                    f"ZOH input on a {DT} s grid; reference RK4 at {DT / fine:g} s",
        "steps": n,
        "compile_s": compile_s,
        "compiled_rk4_us_per_step": c_s / n * 1e6,
        "compiled_rk4_us_per_step_100k_rollout": long_s / n_long * 1e6,
        "vm_rk4_us_per_step": vm_s / n * 1e6,
        "numpy_rk4_us_per_step": np_s / n * 1e6,
        "speedup_compiled_vs_numpy": np_s / c_s,
        "speedup_compiled_vs_vm": vm_s / c_s,
        "rk4_dt": DT,
        "rk4_pitch_rmse_rad": target,
        "rk4_compiled_wall_s": c_s,
        "adaptive_at_matched_pitch_accuracy": adaptive,
    }
    text = json.dumps(result, indent=2)
    print(text)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text + "\n")


if __name__ == "__main__":
    main()
