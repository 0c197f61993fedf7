"""Closed-loop MPC demo: the tracking MPC flies the calm emulator (the "real aircraft") through
a pitch step and a climb, once with the hybrid step and once with physics-only RK4 as the
prediction model. Prints JSON (tracking RMSE, solve times) and saves a PNG.

Usage: ``python analysis/mpc_demo.py [--horizon 20] [--dt 0.05] [--out results/mpc]``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from uavdyn.airframes import load_airframe  # noqa: E402
from uavdyn.linear import trim  # noqa: E402
from uavdyn.mpc import RELU_SMOOTHING, SCENARIOS  # noqa: E402
from uavdyn.mpc.study import fly_all, prediction_models, summarise  # noqa: E402


def plot(results: dict, path: Path) -> None:
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    for col, sc in enumerate(SCENARIOS):
        for model, style in (("hybrid", "r-"), ("physics", "b--")):
            res = results[(sc.name, model)][1]
            if sc.tracked == "theta":
                axes[0, col].plot(res.time, np.degrees(res.states[:, 3]), style, label=model)
            else:
                axes[0, col].plot(res.time, res.states[:, 4], style, label=model)
            axes[1, col].plot(res.time[:-1], res.solve_times_s * 1e3, style, label=model)
        res = results[(sc.name, "physics")][1]
        ref = np.degrees(res.theta_ref) if sc.tracked == "theta" else res.h_ref
        axes[0, col].plot(res.time[1:], ref, "k:", label="reference")
        axes[0, col].set_ylabel("pitch (deg)" if sc.tracked == "theta" else "altitude (m)")
        axes[0, col].set_title(sc.name)
        axes[1, col].set_ylabel("solve time (ms)")
        axes[1, col].set_xlabel("time (s)")
        for ax in axes[:, col]:
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--airframe", default="aerosonde")
    parser.add_argument("--weights", default=None)
    parser.add_argument("--horizon", type=int, default=20)
    parser.add_argument("--dt", type=float, default=0.05)
    parser.add_argument("--out", default="results/mpc")
    args = parser.parse_args()
    af = load_airframe(args.airframe)
    point = trim(af)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = fly_all(af, point, prediction_models(af, args.weights), args.horizon, args.dt)
    summary = {"airframe": af.name, "horizon": args.horizon, "dt": args.dt,
               "plant": "calm emulator (actuator lag, unsteady aero), full-state feedback",
               "hybrid_prediction": "shipped weights, ReLU smoothed to softplus k="
                                    f"{RELU_SMOOTHING:g}",
               "scenarios": summarise(results)}
    plot(results, out / "mpc_demo.png")
    text = json.dumps(summary, indent=2)
    (out / "mpc_demo.json").write_text(text + "\n")
    print(text)
    print(f"wrote {out / 'mpc_demo.png'} and {out / 'mpc_demo.json'}")


if __name__ == "__main__":
    main()
