"""Linearised stability of the hybrid discrete map at the presets' trim points: a mode table
(Markdown + JSON) and a pole plot (PNG) comparing the hybrid map, the physics map, exp(A dt)
and the continuous physics poles.

Usage: ``python analysis/stability.py [--dt 0.01] [--out docs/stability]`` (each preset's
shipped safe correction on its identified airframe, unless ``--airframes FILE... --weights
FILE...`` are given; ``docs/stability/`` is this command's output).
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
from uavdyn.integrate import physics_step  # noqa: E402
from uavdyn.learned import hybrid_step, shipped_correction  # noqa: E402
from uavdyn.linear import (  # noqa: E402
    discrete_map_modes,
    mode_table,
    trim,  # noqa: E402
)


def analyse(af, weights: Path, dt: float) -> dict:
    """Hybrid-map and physics-map modes of an airframe (the one the weights were trained on)
    at its nominal trim point."""
    point = trim(af)
    hybrid = discrete_map_modes(hybrid_step(weights, af, compile=False), point, dt)
    plain = discrete_map_modes(physics_step(af), point, dt)
    return {"airframe": af, "point": point, "hybrid": hybrid, "rk4": plain, "weights": weights}


def plot(results: list[dict], path: Path) -> None:
    fig, axes = plt.subplots(len(results), 2, figsize=(11, 4.8 * len(results)), squeeze=False)
    theta = np.linspace(0, 2 * np.pi, 400)
    for row, res in zip(axes, results):
        h, r = res["hybrid"], res["rk4"]
        ax = row[0]
        ax.plot(np.cos(theta), np.sin(theta), "k-", lw=0.6, label="unit circle")
        ax.plot(r.exact_eigenvalues.real, r.exact_eigenvalues.imag, "ko", mfc="none", ms=10,
                label="exp(A dt)")
        ax.plot(r.map_eigenvalues.real, r.map_eigenvalues.imag, "b+", ms=10, label="physics map")
        ax.plot(h.map_eigenvalues.real, h.map_eigenvalues.imag, "rx", ms=8, label="hybrid map")
        lam = np.concatenate([r.exact_eigenvalues, h.map_eigenvalues])
        span = max(np.abs(lam - 1).max() * 1.5, 1e-3)
        ax.set_xlim(1 - span, 1 + span)
        ax.set_ylim(-span, span)
        ax.set_title(f"{res['airframe'].name}: z-plane near 1 (dt = {h.dt:g} s)")
        ax.set_aspect("equal")
        ax.legend(fontsize=8)
        ax = row[1]
        phys = np.array([m.eigenvalue for m in r.physics_modes] +
                        [m.eigenvalue.conjugate() for m in r.physics_modes
                         if m.eigenvalue.imag > 0])
        ax.plot(phys.real, phys.imag, "ko", mfc="none", ms=10, label="physics A")
        ax.plot(h.map_continuous.real, h.map_continuous.imag, "rx", ms=8,
                label="hybrid log(lambda)/dt")
        ax.axvline(0, color="k", lw=0.6)
        ax.set_xlabel("real (1/s)")
        ax.set_ylabel("imag (rad/s)")
        ax.set_title(f"{res['airframe'].name}: continuous-equivalent poles")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dt", type=float, default=0.01)
    parser.add_argument("--out", default="results/stability")
    parser.add_argument("--airframes", nargs="+", default=["aerosonde", "f450"])
    parser.add_argument("--weights", nargs="*", default=None,
                        help="weight files, one per airframe file given with --airframes "
                             "(default: each preset's shipped safe correction on its "
                             "identified airframe)")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.weights:
        pairs = [(Path(w), load_airframe(n)) for n, w in zip(args.airframes, args.weights)]
    else:
        pairs = [shipped_correction(n) for n in args.airframes]
    results = [analyse(af, w, args.dt) for w, af in pairs]
    lines, summary = [], []
    for res in results:
        h, r = res["hybrid"], res["rk4"]
        lines += [f"## {res['airframe'].name} at {res['point'].airspeed:g} m/s, dt = {h.dt:g} s",
                  f"weights: `{Path(res['weights']).name}`", "", "Physics model (continuous):", "",
                  mode_table(h.physics_modes), "", "Hybrid map, continuous equivalents:", "",
                  mode_table(h.map_modes), "", "Hybrid map eigenvalues:", "", h.table(), ""]
        verdict = ("every mode of the hybrid map is stable" if not h.unstable else
                   f"unstable map eigenvalues: {h.unstable} (made so by the correction: "
                   f"{h.made_unstable})")
        lines += [f"Verdict: {verdict}.", ""]
        summary.append({
            "airframe": res["airframe"].name, "dt": h.dt,
            "hybrid_map_eigenvalues": [[z.real, z.imag] for z in h.map_eigenvalues],
            "rk4_map_eigenvalues": [[z.real, z.imag] for z in r.map_eigenvalues],
            "exp_A_dt_eigenvalues": [[z.real, z.imag] for z in h.exact_eigenvalues],
            "hybrid_modes": [m.as_dict() for m in h.map_modes],
            "physics_modes": [m.as_dict() for m in h.physics_modes],
            "unstable": h.unstable, "made_unstable": h.made_unstable,
        })
    (out / "modes.md").write_text("# Modes of the hybrid discrete map\n\nWritten by `python "
                                  f"analysis/stability.py --dt {args.dt:g} --out {args.out}`.\n\n"
                                  + "\n".join(lines))
    (out / "modes.json").write_text(json.dumps(summary, indent=2, default=str) + "\n")
    plot(results, out / "poles.png")
    print("\n".join(lines))
    print(f"wrote {out / 'modes.md'}, {out / 'modes.json'}, {out / 'poles.png'}")


if __name__ == "__main__":
    main()
