"""The state of one output-error fit (:class:`_Fit`, :class:`_Outcome`), its time grid and its
data-derived scales: the log interval and RK sub-steps, the state weights, the measurement
noise and the lag pre-roll length."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.flightdata import Sortie
from uavdyn.identify.errors import IdentifyError
from uavdyn.identify.problem import _Problem
from uavdyn.identify.result import DEFAULT_SUBSTEPS
from uavdyn.identify.unknowns import Unknowns, control_names
from uavdyn.identify.windows import N_BODY, Windows, physics_windows
from uavdyn.integrate import EvalGrid, substeps_for
from uavdyn.model import ModelStructure

STATE_WEIGHT_FLOOR = 1e-6
PREROLL_TAUS = 8.0       # the lag pre-roll covers this many time constants (exp(-8) = 3e-4) ...
PREROLL_MIN_S = 1.0      # ... and at least this long


def measurement_noise(sorties: list[Sortie]) -> np.ndarray:
    """Per-state standard deviation of white measurement noise, from the second differences
    of the logged states (``var(d2 y) = 6 sigma^2`` for white noise; a smooth flight signal adds
    little at logging rates), floored so noise-free data pin the start states."""
    d2 = np.concatenate([np.diff(s.states, 2, axis=0) for s in sorties])
    sigma = np.sqrt(np.mean(d2**2, axis=0) / 6.0)
    return np.maximum(sigma, 1e-9 * (1.0 + np.abs(np.concatenate([s.states for s in sorties]))
                                     .max(axis=0)))


MAX_DEFAULT_DT = 0.005  # default RK step: the log interval in whole sub-steps of at most this


def _time_grid(train: list[Sortie], dt: float | None, substeps: int | None
               ) -> tuple[float, int, int]:
    """The log interval of the data, the RK steps per grid interval and the grid's stride in
    log samples (``dt`` longer than the log interval: several samples per step)."""
    sample_dt = float(np.median(np.diff(train[0].time)))
    if dt is not None:
        grid = EvalGrid(sample_dt, dt)
        S, stride = grid.substeps, grid.stride
    else:
        S, stride = int(substeps or substeps_for(sample_dt, MAX_DEFAULT_DT, DEFAULT_SUBSTEPS)), 1
        if S < 1:
            raise IdentifyError(f"substeps must be >= 1, got {substeps}")
    return sample_dt, S, stride


def _nominal_weights(airframe: Airframe, windows: Windows, interval: float, substeps: int
                     ) -> np.ndarray:
    """State weights: the nominal model's residual RMS per state (puts every state on one
    scale)."""
    resid0 = (physics_windows(airframe, windows, interval, substeps)
              - windows.y).reshape(-1, N_BODY)
    with np.errstate(all="ignore"):
        rms0 = np.sqrt(np.nanmean(np.where(np.abs(resid0) < 1e6, resid0, np.nan)**2, axis=0))
    return 1.0 / np.maximum(np.nan_to_num(rms0, nan=1.0), STATE_WEIGHT_FLOOR)


def _preroll_samples(tau: float, interval: float) -> int:
    """Samples of lag pre-roll for a time constant ``tau``, rounded up to a power of two (a
    few lengths only: each is a compiled library)."""
    need = math.ceil(max(PREROLL_MIN_S, PREROLL_TAUS * tau) / interval)
    return 1 << (int(need) - 1).bit_length()


@dataclass
class _Fit:
    """What the stages of one identification share: the request, the training windows on the
    time grid, the scaled unknowns, the state weights and the compiled problem (rebuilt when
    the lag pre-roll grows), with its data vectors cached per delay candidate."""

    airframe: Airframe
    continuous: list[str]
    searched: list[str]
    structure: ModelStructure
    windows: Windows
    L: int
    interval: float
    substeps: int
    stride: int
    unknowns: Unknowns
    rho_index: int | None
    ratios: np.ndarray
    noise: np.ndarray
    weights: np.ndarray
    weights_nominal: np.ndarray
    estimate_x0: bool
    envelope: dict = field(default_factory=dict)
    problem: _Problem | None = None
    data_cache: dict[tuple, np.ndarray] = field(default_factory=dict)
    prior: np.ndarray | None = None  # weights of the parameters' prior rows (none: no prior)
    window_weights: np.ndarray | None = None  # per window (its sortie's); None: all 1

    @property
    def controls(self) -> tuple[str, ...]:
        return control_names(self.airframe.kind)

    def new_problem(self, preroll: int) -> _Problem:
        """The problem with a lag pre-roll of ``preroll`` samples (the data cache keys on it)."""
        self.problem = _Problem(self.structure, self.unknowns.index, self.windows.count,
                                self.L, preroll, self.interval, self.substeps, self.rho_index,
                                self.estimate_x0)
        return self.problem

    def data_for(self, d) -> np.ndarray:
        """The data vector of the current problem with the commands delayed by ``d``."""
        key = (tuple(d), self.problem.M)
        if key not in self.data_cache:
            u = self.unknowns
            self.data_cache[key] = self.problem.pack(self.windows, self.structure, d,
                                                     self.ratios, self.weights, self.noise,
                                                     u.p_nom, u.scale)
            self.data_cache[key]["prior"] = self.prior
            if self.window_weights is not None:
                self.data_cache[key]["window_weights"] = self.window_weights
        return self.data_cache[key]

    def with_dx(self, th: np.ndarray) -> np.ndarray:
        """The unknowns with the recorded start states."""
        return np.concatenate([th, np.zeros(self.problem.n_dx)])

    def taus_of(self, th: np.ndarray) -> np.ndarray:
        """The structure's time constants at the scaled unknowns ``th``; a rate-limited
        actuator's at least the one whose pre-roll also covers a slew over its full travel."""
        p = self.unknowns.p_of(th)
        bounds = self.airframe.control_bounds()
        return np.array([max(p[i], 0.0 if k is None else p[k] * (bounds[c][1] - bounds[c][0])
                             / PREROLL_TAUS)
                         for c, i, k in zip(self.structure.lag_indices,
                                            self.structure.tau_indices,
                                            self.structure.slew_indices)])


@dataclass
class _Outcome:
    """The solved fit: unknowns ``z``, delays, residual and Jacobian there, and its history."""

    z: np.ndarray
    delays: list[int]
    r: np.ndarray
    J: object  # scipy.sparse matrix
    cost_initial: float
    iterations: int
    stats: dict
    log: list[dict]
