"""Searches of an identification: integer delays and time-constant starts, delay re-checks."""

from __future__ import annotations

import math

import numpy as np

from uavdyn.identify.errors import IdentifyError
from uavdyn.identify.lm import solve_bounded
from uavdyn.identify.problem import _Problem
from uavdyn.identify.unknowns import DELAY_PREFIX, START_GRIDS

RECHECK_STEPS = 4        # Gauss-Newton steps at a neighbouring delay before comparing costs
SEARCH_ROUNDS = 3        # rounds of the delay / tau start coordinate search


def _search(problem: _Problem, data_for, with_dx, theta: np.ndarray, delays: list[int],
            searched: list[str], from_zero: list[int], names: list[str], scale: np.ndarray,
            max_delay: int, lo: np.ndarray, hi: np.ndarray, controls: tuple[str, ...],
            log: list[dict]) -> tuple[np.ndarray, list[int]]:
    """Coordinate search on the cost (start states as recorded, continuous parameters at their
    start values) over each searched delay in ``0..max_delay`` and each time constant or slew
    time fitted from 0 over its :data:`START_GRIDS` grid, until a round changes nothing."""
    theta, delays = theta.copy(), list(delays)
    for round_ in range(SEARCH_ROUNDS):
        changed = False
        for c in searched:
            k = controls.index(c)
            costs = []
            for d in range(max_delay + 1):
                trial = list(delays)
                trial[k] = d
                costs.append(problem.cost(with_dx(theta), data_for(trial)))
            finite = [v for v in costs if math.isfinite(v)]
            if round_ == 0 and (not finite or max(finite) - min(finite)
                                <= 1e-12 * max(abs(min(finite)), 1e-300)):
                raise IdentifyError(f"the training data do not excite parameter(s) "
                                    f"['{DELAY_PREFIX}{c}']: the cost is the same for every "
                                    f"delay 0..{max_delay} (is the {c} command ever moved?)")
            best = int(np.argmin(costs))
            log.append({"step": f"search {DELAY_PREFIX}{c}", "round": round_,
                        "costs": costs, "chosen": best})
            changed |= best != delays[k]
            delays[k] = best
        for j in from_zero:
            costs, grid = [], START_GRIDS[names[j]][0]
            for value in grid:
                trial = theta.copy()
                trial[j] = min(max(value / scale[j], lo[j]), hi[j])
                costs.append(problem.cost(with_dx(trial), data_for(delays)))
            best = float(grid[int(np.argmin(costs))])
            log.append({"step": f"start {names[j]}", "round": round_, "grid": list(grid),
                        "costs": costs, "chosen": best})
            changed |= not math.isclose(best / scale[j], theta[j])
            theta[j] = min(max(best / scale[j], lo[j]), hi[j])
        if not changed or not (searched and from_zero):
            break
    return theta, delays


def _recheck_delays(problem: _Problem, data_for, z: np.ndarray, cost: float, delays: list[int],
                    searched: list[str], controls: tuple[str, ...], max_delay: int,
                    lag_shift: dict[str, list[tuple[int, float]]], lower: np.ndarray,
                    upper: np.ndarray, log: list[dict]
                    ) -> tuple[list[int], np.ndarray] | None:
    """Re-check each searched delay at +-1 after the fit: a neighbour is compared at its own
    best continuous values, approximated by a few Gauss-Newton steps from the fitted ones (a
    lag fitted on the same control, whose time constant trades against the delay, starts
    shifted by one sample the other way); while a neighbour lowers the cost, the walk goes on
    in that direction. Returns the improved delays and unknowns (to refit from), or None when
    the fitted delays stand."""
    best, best_z, best_cost = list(delays), z, cost
    for c in searched:
        k = controls.index(c)
        for direction in (-1, 1):
            here, here_z, moved = best[k], best_z, False
            while 0 <= here + direction <= max_delay:
                trial = list(best)
                trial[k] = here + direction
                start = here_z.copy()
                for j, unit in lag_shift.get(c, ()):
                    start[j] = min(max(start[j] - direction * unit, lower[j]), upper[j])
                data = data_for(trial)
                z_try, value = _a_few_steps(problem, start, data, lower, upper)
                at_fit = problem.cost(here_z, data)
                if at_fit < value:
                    z_try, value = here_z, at_fit
                log.append({"step": f"re-check {DELAY_PREFIX}{c}", "delay": trial[k],
                            "cost": value, "fitted_cost": best_cost})
                if not value < best_cost * (1 - 1e-9):
                    break
                best, best_z, best_cost, moved = trial, z_try, value, True
                here, here_z = trial[k], z_try
            if moved:
                break  # this control moved one way: the other way is uphill
    return None if best == list(delays) else (best, best_z)


def _a_few_steps(problem: _Problem, z: np.ndarray, data, lower: np.ndarray, upper: np.ndarray
                 ) -> tuple[np.ndarray, float]:
    """:data:`RECHECK_STEPS` steps of the fit's own solver (for comparing delay candidates at
    their own best continuous values without a full solve)."""
    out = solve_bounded(lambda x: problem.evaluate(x, data), lambda x: problem.cost(x, data),
                        z, lower, upper, RECHECK_STEPS)
    return out.z, out.cost
