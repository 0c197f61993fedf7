"""Closed-loop MPC demo: the tracking MPC flies the calm emulator (the "real aircraft") through
every scenario of the airframe's kind (pitch step, climb, speed step), once with the hybrid
prediction and once with physics RK4, and saves one PNG (reference vs response, solve times)
and a JSON summary.

Usage: ``python analysis/mpc_demo.py [--airframe aerosonde] [--horizon 20] [--sqp]
[--out docs/mpc]``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from uavdyn.mpc import SCENARIO_NAMES, MPCConfig  # noqa: E402
from uavdyn.mpc.study import fly_all, prediction_models, summarise  # noqa: E402


def plot(results: dict, path: Path, title: str) -> None:
    fig, axes = plt.subplots(2, len(SCENARIO_NAMES), figsize=(14, 7))
    for col, name in enumerate(SCENARIO_NAMES):
        sc = None
        for model, style in (("hybrid", "r-"), ("physics", "b--")):
            if (name, model) not in results:  # no correction ships for this preset
                continue
            sc, res = results[(name, model)]
            y = {"theta": np.degrees(res.states[:, 3]), "h": res.states[:, 4],
                 "speed": res.speed}[sc.tracked]
            axes[0, col].plot(res.time, y, style, label=f"{model} prediction")
            ok = res.success
            axes[1, col].plot(res.time[:-1][ok], res.solve_times_s[ok] * 1e3, style[0] + ".",
                              ms=2, label=f"{model} ({ok.mean():.0%} solved)")
        ref = {"theta": np.degrees(res.theta_ref), "h": res.h_ref,
               "speed": res.speed_ref}[sc.tracked]
        axes[0, col].plot(res.time[1:], ref, "k:", label="reference")
        axes[0, col].set_ylabel({"theta": "pitch (deg)", "h": "altitude (m)",
                                 "speed": "speed (m/s)"}[sc.tracked])
        axes[0, col].set_title(name)
        axes[1, col].set_ylabel("solve time (ms)")
        axes[1, col].set_xlabel("time (s)")
        for ax in axes[:, col]:
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--airframe", default="aerosonde")
    parser.add_argument("--weights", default=None)
    parser.add_argument("--horizon", type=int, default=20)
    parser.add_argument("--sqp", action="store_true", help="full SQP instead of RTI")
    parser.add_argument("--out", default="results/mpc")
    args = parser.parse_args()
    mode = "sqp" if args.sqp else "rti"
    setup = prediction_models(args.airframe, args.weights, mode)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = fly_all(setup, MPCConfig(horizon=args.horizon, mode=mode))
    stem = f"mpc_demo_{setup.plant_airframe.name}_{mode}_h{args.horizon}"
    summary = {"airframe": setup.plant_airframe.name, "mode": mode, "horizon": args.horizon,
               "plant": f"calm emulator of {setup.plant_airframe.name}",
               "prediction": {k: m.description for k, m in setup.models.items()},
               "missing": setup.missing,
               "scenarios": summarise(results)}
    note = "; no hybrid: no correction ships" if setup.missing else ""
    plot(results, out / f"{stem}.png",
         f"{setup.plant_airframe.name}: {mode.upper()} horizon {args.horizon}, dt 0.05 s, calm "
         f"emulator{note}")
    (out / f"{stem}.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps(summary, indent=2))
    print(f"wrote {out / (stem + '.png')} and {out / (stem + '.json')}")


if __name__ == "__main__":
    main()
