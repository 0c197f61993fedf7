"""Evaluation: one-step, horizon and free-run predictions of any step Function against target
trajectories, and the error metrics."""

from uavdyn.evaluation.metrics import (
    METRIC_STATES,
    MODES,
    Solver,
    error_growth,
    error_stats,
    evaluate_trajectory,
    fine_reference,
    pitch_rmse,
    pooled_stats,
    predict_windows,
    sortie_altitude,
    sortie_free_run,
    step_states,
)

__all__ = ["METRIC_STATES", "MODES", "Solver", "error_growth", "error_stats",
           "evaluate_trajectory", "fine_reference", "pitch_rmse", "pooled_stats",
           "predict_windows", "sortie_altitude", "sortie_free_run", "step_states"]
