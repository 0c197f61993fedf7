"""The unknowns of an identification: the names asked for, their scaling and their bounds."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavdyn.airframes import BOUNDS, CONTROL_RANGES, DELAY_MAX_SAMPLES, SIGNS, Airframe, sign_range
from uavdyn.airframes.tables import VALUE_LIMITS
from uavdyn.flightdata import Sortie
from uavdyn.identify.errors import IdentifyError
from uavdyn.model import LAG_PARAMS, SLEW_PARAMS

DELAY_PREFIX = "delay_"
TAU_NAMES = frozenset(t for lags in LAG_PARAMS.values() for t in lags.values())
TAU_GRID = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5)   # s, start candidates of a time constant at 0
TAU_BOUNDS = (1e-3, 10.0)                       # s, a fitted time constant stays inside
TAU_SCALE = 0.1                                 # s, unit of the unknown of a tau fitted from 0
SLEW_NAMES = frozenset(s for slews in SLEW_PARAMS.values() for s in slews.values())
# s per unit, start candidates of a slew time (1 / rate limit) at 0; the first is as good as
# no rate limit (100 units/s)
SLEW_GRID = (0.01, 0.1, 0.2, 0.5, 1.0, 2.0)
# a fitted slew time stays inside: at 0 the cost is flat in it (the rate-limited lag is even
# in the slew), so the data could never say anything there
SLEW_BOUNDS = (0.01, 10.0)
SLEW_SCALE = 0.5                                # s per unit, unit of a slew fitted from 0
# per name: the start grid, the unknown's unit from 0, and the range a fit stays inside
START_GRIDS = {**{n: (TAU_GRID, TAU_SCALE, TAU_BOUNDS) for n in TAU_NAMES},
               **{n: (SLEW_GRID, SLEW_SCALE, SLEW_BOUNDS) for n in SLEW_NAMES}}


def control_names(kind: str) -> tuple[str, ...]:
    return tuple(n for n, _ in CONTROL_RANGES[kind])


def _check_request(airframe: Airframe, names: list[str], sorties: list[Sortie],
                   max_delay: int) -> tuple[list[str], list[str]]:
    """Split ``names`` into parameters of ``p`` and searched delays (control names)."""
    if not names:
        raise IdentifyError("no parameter named: give at least one with --params")
    if len(set(names)) != len(names):
        raise IdentifyError(f"parameter named twice in {names}")
    controls = control_names(airframe.kind)
    delay_names = [DELAY_PREFIX + c for c in controls]
    bad_delays = [n for n in names if n.startswith(DELAY_PREFIX) and n not in delay_names]
    if bad_delays:
        raise IdentifyError(f"{bad_delays} not a delay of the {airframe.kind} model; valid "
                            f"delays: {', '.join(delay_names)}")
    unknown = [n for n in names if n not in airframe.param_names and n not in delay_names]
    if unknown:
        raise IdentifyError(f"parameter(s) {unknown} are not in the {airframe.kind} model of "
                            f"'{airframe.name}'; choose from "
                            f"{', '.join(airframe.param_names + tuple(delay_names))}")
    if (isinstance(max_delay, bool) or not isinstance(max_delay, int)
            or not 1 <= max_delay <= DELAY_MAX_SAMPLES):
        raise IdentifyError(f"max_delay must be a whole number of samples in "
                            f"[1, {DELAY_MAX_SAMPLES}], got {max_delay!r}")
    if not sorties:
        raise IdentifyError("no training sorties")
    wrong = [s.name for s in sorties if s.kind != airframe.kind]
    if wrong:
        raise IdentifyError(f"sortie(s) {wrong[:3]} are of another kind than airframe "
                            f"'{airframe.name}' ({airframe.kind})")
    continuous = [n for n in names if n not in delay_names]
    check_signs(airframe, continuous)
    searched = [n[len(DELAY_PREFIX):] for n in names if n in delay_names]
    return continuous, searched


@dataclass
class Unknowns:
    """The continuous unknowns of a fit: ``p[index] = p_nom[index] + scale * theta``, with
    ``theta`` starting at ``theta0`` (0, or a time constant or slew time fitted from 0 at the
    middle of its :data:`START_GRIDS` grid, ``from_zero``) and bounded by ``[lo, hi]``."""

    index: list[int]
    p_nom: np.ndarray
    scale: np.ndarray
    theta0: np.ndarray
    from_zero: list[int]
    lo: np.ndarray
    hi: np.ndarray

    def p_of(self, theta: np.ndarray) -> np.ndarray:
        """The full parameter vector at the scaled unknowns ``theta``."""
        p = self.p_nom.copy()
        p[self.index] = self.p_nom[self.index] + self.scale * theta
        return p


def scaled_unknowns(airframe: Airframe, continuous: list[str], relative_bound: float | None,
                    bounds: dict[str, tuple[float, float]] | None = None) -> Unknowns:
    """The unknowns of the parameters ``continuous``, each scaled by its nominal magnitude (a
    time constant or slew time at 0: its :data:`START_GRIDS` unit; another parameter at 0:
    1)."""
    index = [airframe.param_names.index(n) for n in continuous]
    p_nom = airframe.p
    unit = np.array([START_GRIDS[n][1] if n in START_GRIDS else 1.0 for n in continuous])
    from_zero = [j for j, n in enumerate(continuous)
                 if n in START_GRIDS and p_nom[index[j]] == 0]
    scale = (np.where(np.abs(p_nom[index]) > 0, np.abs(p_nom[index]), unit) if continuous
             else np.zeros(0))
    theta = np.zeros(len(continuous))
    for j in from_zero:
        grid = START_GRIDS[continuous[j]][0]
        theta[j] = grid[len(grid) // 2] / scale[j]
    unknown = sorted(set(bounds or {}) - set(continuous))
    if unknown:
        raise IdentifyError(f"bounds given for {unknown}, which are not fitted ({continuous})")
    lo, hi = _theta_bounds(airframe, continuous, p_nom, scale, relative_bound, bounds or {})
    return Unknowns(index, p_nom, scale, theta, from_zero, lo, hi)


def _at_bound(value: float, low: float, high: float) -> str:
    """Which bound an estimate ended on, if any: within 1e-4 of the allowed range in the fit's
    units (the nominal value's magnitude; 1 for a parameter whose nominal value is 0), a range
    counted as at most 2 units so a zero-nominal parameter's wide physical range (e.g. 0..1e3)
    does not flag a small but clearly interior estimate."""
    span = 1e-4 * max(min(high - low, 2.0) if math.isfinite(high - low) else 1.0, 1e-300)
    return "lower" if value - low <= span else "upper" if high - value <= span else ""



def _bound_of(airframe: Airframe, name: str) -> tuple[float, float, bool, bool]:
    """The physical range of a parameter ``(low, high, low_open, high_open)``: the schema's
    bound, narrowed to the sign physics gives the derivative by its meaning and the sign
    convention (:data:`uavdyn.airframes.SIGNS`: ``C_L_alpha > 0``, ``C_m_q < 0``,
    ``C_m_delta_e < 0``, ``C_m_alpha < 0`` unless the file declares ``relaxed_stability``;
    other coefficients may take either sign, a time constant is >= 0, a share lies in
    [0, 1]), a table's value limit, or :data:`TAU_BOUNDS` / :data:`SLEW_BOUNDS` for a time
    constant / slew time."""
    if name in START_GRIDS:
        return (*START_GRIDS[name][2], False, False)
    if name in BOUNDS[airframe.kind]:
        bound = BOUNDS[airframe.kind][name]
        low, high, low_open, high_open = bound.low, bound.high, bound.low_open, bound.high_open
        signed = sign_range(airframe.kind, name, airframe.relaxed_stability)
        if signed is not None and signed[0] > low:
            low, low_open = signed[0], True
        if signed is not None and signed[1] < high:
            high, high_open = signed[1], True
        return low, high, low_open, high_open
    table = name.split("_table_")[0]
    if table in VALUE_LIMITS:
        return -VALUE_LIMITS[table], VALUE_LIMITS[table], False, False
    return -math.inf, math.inf, True, True


def check_signs(airframe: Airframe, names: list[str]) -> None:
    """Refuse a fit starting from a file value of the wrong sign (:data:`SIGNS`)."""
    for name in names:
        signed = sign_range(airframe.kind, name, airframe.relaxed_stability)
        value = float(getattr(airframe.params, name)) if signed is not None else 0.0
        if signed is not None and not signed[0] < value < signed[1]:
            sign = SIGNS[airframe.kind][name]
            hint = (" (an airframe unstable by design: declare relaxed_stability = true in "
                    "the file)" if sign.relaxable else "")
            raise IdentifyError(f"the fit of '{name}' starts from its value {value:g} in the "
                                f"airframe file '{airframe.name}', of the wrong sign: "
                                f"{sign.why}{hint}")


def _theta_bounds(airframe: Airframe, names: list[str], p_nom: np.ndarray, scale: np.ndarray,
                  relative_bound: float | None, bounds: dict[str, tuple[float, float]]
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the scaled unknowns: the physical range (:func:`_bound_of`), narrowed by a
    user's ``bounds[name] = (low, high)`` and, where ``relative_bound`` is given, to
    ``(1 +- relative_bound)`` of a nonzero nominal value (sign kept)."""
    lo = np.empty(len(names))
    hi = np.empty(len(names))
    for j, name in enumerate(names):
        p0 = p_nom[airframe.param_names.index(name)]
        low, high, _, _ = _bound_of(airframe, name)
        if name in bounds:
            low, high = max(low, bounds[name][0]), min(high, bounds[name][1])
            if not low <= p0 <= high:
                raise IdentifyError(f"the fit of '{name}' starts from its value {p0:g} in the "
                                    f"airframe file, outside the bounds [{low:g}, {high:g}] "
                                    "given for it")
        if relative_bound is not None and p0 != 0:
            low = max(low, p0 - relative_bound * abs(p0))
            high = min(high, p0 + relative_bound * abs(p0))
        lo[j], hi[j] = (low - p0) / scale[j], (high - p0) / scale[j]
    return lo, hi


def project_inside(airframe: Airframe, name: str, value: float) -> float:
    """``value`` projected into the parameter's physical range (an open bound: just inside),
    so a fit overshooting a bound by round-off still writes its file."""
    low, high, low_open, high_open = _bound_of(airframe, name)
    if value <= low:
        value = np.nextafter(low, math.inf) if low_open else low
    if value >= high:
        value = np.nextafter(high, -math.inf) if high_open else high
    return float(value)
