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
    horizon_predictions,
    pitch_rmse,
    pooled_stats,
    solver_windows,
)
from uavdyn.evaluation.spread import (
    ErrorShare,
    PairedComparison,
    PooledError,
    SortieError,
    compare_paired,
    error_share,
    pooled_rmse,
    pooled_with_interval,
    squared_error,
)
from uavdyn.evaluation.timing import Timing, interleaved_timing, ratio
from uavdyn.integrate import sortie_free_run, sortie_p, step_states

__all__ = ["METRIC_STATES", "MODES", "Solver", "error_growth", "error_stats",
           "evaluate_trajectory", "fine_reference", "horizon_predictions", "pitch_rmse",
           "pooled_stats",
           "solver_windows", "sortie_free_run", "sortie_p", "step_states",
           "ErrorShare", "PairedComparison", "PooledError", "SortieError", "compare_paired",
           "error_share", "pooled_rmse",
           "pooled_with_interval", "squared_error", "Timing", "interleaved_timing", "ratio"]
