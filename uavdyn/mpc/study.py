"""Closed-loop MPC studies: every scenario flown with every prediction model (hybrid step,
physics-only RK4) against the calm emulator, and their summary figures."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uavdyn.integrate import physics_step
from uavdyn.learned import hybrid_step, shipped_weights
from uavdyn.mpc.tracking import RELU_SMOOTHING, SCENARIOS, MPCConfig, run_scenario


def prediction_models(airframe, weights: Path | None) -> dict:
    """The two prediction models compared: the hybrid step and physics-only RK4 (the
    airframe's own physics step: on the augmented state when it has actuator lags/delays)."""
    return {"hybrid": hybrid_step(weights or shipped_weights(airframe.name), airframe,
                                  compile=False, relu_smoothing=RELU_SMOOTHING),
            "physics": physics_step(airframe)}


def fly_all(airframe, point, models: dict, horizon: int, dt: float) -> dict:
    """Every scenario with every prediction model: closed-loop results keyed (scenario, model)."""
    config = MPCConfig(horizon=horizon, dt=dt)
    return {(sc.name, name): (sc, run_scenario(sc, step, airframe, point, config))
            for sc in SCENARIOS for name, step in models.items()}


def summarise(results: dict) -> dict:
    """Tracking RMSE, solve-time statistics and success rate per scenario and model."""
    out = {}
    for (scenario_name, model), (sc, res) in results.items():
        rmse = res.rmse(sc.tracked, t_from=sc.start)
        out.setdefault(scenario_name, {})[model] = {
            "tracked": sc.tracked, "tracking_rmse": rmse,
            "tracking_rmse_unit": "rad" if sc.tracked == "theta" else "m",
            "solve_ms_median": float(np.median(res.solve_times_s) * 1e3),
            "solve_ms_max": float(np.max(res.solve_times_s) * 1e3),
            "all_solves_succeeded": bool(res.success.all()),
            "solve_success_rate": float(res.success.mean()),
        }
    return out
