"""Monte Carlo with a controller in the loop: each run's dispersed airframe (its parameters,
initial state, trim speed and gust intensity drawn from ``(seed, run)`` exactly as a study's
runs) flies a closed-loop scenario (pitch step, climb, speed step) with any
:class:`uavdyn.mpc.Controller` (the real-time-iteration or full-SQP MPC), its turbulence
included; the controller predicts with its own (nominal) model, the plant is the run's
airframe. Per run: tracking RMSE, largest pitch, failed solves, fallbacks, departure. Then
which dispersion drives the worst runs: for each drawn quantity, the share of the tracking
error's rank variance its quartile explains (a correlation ratio: it sees a V-shaped effect,
such as a derivative whose error either way from the controller's model hurts, which a
correlation misses), its rank correlation with the error, and its shift, in standard
deviations, over the worst tenth of the runs.

The batch studies of :mod:`uavdyn.montecarlo.study` fly open loop or under a linear state
feedback compiled into the run (LQR, thousands of runs per second); this flies a controller
that solves an optimisation each step, one run after the other (about 0.1 s per run of the
8 s pitch step with the horizon-20 RTI).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import spearmanr

from uavdyn.airframes import Airframe, AirframeError
from uavdyn.linear import TrimError, trim
from uavdyn.linear.trim import trim_state
from uavdyn.model import structure_of
from uavdyn.montecarlo.batch import gust_step
from uavdyn.montecarlo.dispersions import STATE_KEYS, Dispersions
from uavdyn.montecarlo.spec import MonteCarloError
from uavdyn.mpc import Controller, Scenario
from uavdyn.mpc.tracking import fly_closed_loop

OUTCOMES = ("run", "trim_ok", "departed", "tracking_rmse", "max_pitch_error_deg",
            "max_abs_pitch_deg", "bound_share", "rate_share", "failed_solves", "fallbacks",
            "median_solve_ms")
# a control within this share of its travel from a bound is on it; a change within this share
# of the rate limit's step is on the rate limit
ACTIVE_TOLERANCE = 1e-6
WORST_SHARE = 0.1  # the worst runs: this share of them (at least one)
SHOWN_WORST = 10  # the worst runs a summary names


@dataclass(frozen=True)
class Driver:
    """How one drawn quantity goes with the tracking error over the runs.

    Attributes
    ----------
    column : str
        The drawn quantity (``params.C_m_alpha``, ``initial.theta``, ``gust.intensity``...).
    explained : float
        Share (0..1) of the variance of the runs' tracking-error ranks explained by the
        quantity's quartile (halves below 8 runs); NaN for a quantity that did not vary.
    spearman : float
        Rank correlation with the tracking error (a departed run ranks worst); NaN for a
        quantity that did not vary.
    worst_shift_sd : float
        Mean over the worst runs minus the mean over all, in standard deviations of the
        quantity.
    """

    column: str
    explained: float
    spearman: float
    worst_shift_sd: float


@dataclass(frozen=True)
class ControlledRuns:
    """The runs of a controller-in-the-loop Monte Carlo.

    Attributes
    ----------
    columns : tuple of str
        :data:`OUTCOMES`, then each drawn quantity (parameters by their dispersed value).
    table : ndarray
        One row per run.
    drivers : list of Driver
        Every drawn quantity, the strongest (largest explained share) first.
    scenario : str
        The scenario flown.
    """

    columns: tuple[str, ...]
    table: np.ndarray
    drivers: list[Driver]
    scenario: str

    @classmethod
    def from_table(cls, columns: tuple[str, ...], table: np.ndarray, scenario: str
                   ) -> ControlledRuns:
        """The runs of a table (e.g. chunks put together), their drivers computed anew."""
        drawn = list(columns[len(OUTCOMES):])
        return cls(tuple(columns), table, _drivers(tuple(columns), table, drawn), scenario)

    def column(self, name: str) -> np.ndarray:
        """One column of :attr:`table`."""
        return self.table[:, self.columns.index(name)]

    def worst_runs(self) -> np.ndarray:
        """Run numbers of the worst runs (:data:`WORST_SHARE`), worst first."""
        order = np.argsort(-_badness(self))
        return self.column("run")[order[:_n_worst(len(order))]].astype(int)


def gusty_plant(airframe: Airframe, dt: float, gusts: np.ndarray | None):
    """A ``plant_step`` for :func:`uavdyn.mpc.fly_closed_loop`: the airframe's physics step
    (actuator lags and delays included) whose forces see the air-relative velocity, the gusts
    ``[u_g, w_g, q_g]`` (``n x 3``, row k held over interval k; None: calm), plus the
    altitude (trapezoidal integral of the inertial climb rate). State ``[step state..., h]``;
    it feeds back ``[u, w, q, theta, h]``."""
    structure = structure_of(airframe)
    step = gust_step(structure)
    p = np.asarray(airframe.p, float)
    k = [0]

    def hdot(z):
        return z[0] * np.sin(z[3]) - z[1] * np.cos(z[3])

    def plant(z, u):
        z = np.asarray(z, float).ravel()
        if u is None:
            k[0] = 0
            return z, np.r_[z[:4], z[-1]]
        g = gusts[k[0]] if gusts is not None and k[0] < len(gusts) else np.zeros(3)
        k[0] += 1
        x = z[:-1]
        x_next = np.asarray(step(x, np.r_[u, g], p, dt)).ravel()
        h = z[-1] + dt / 2 * (hdot(x) + hdot(x_next))
        z_next = np.r_[x_next, h]
        return z_next, np.r_[z_next[:4], h]

    return plant


def _run_airframe(nominal: Airframe, dispersions: Dispersions, draw, run: int) -> Airframe:
    if not dispersions.params:
        return nominal
    try:
        return nominal.replace(**draw.params(dispersions, nominal))
    except AirframeError as exc:
        raise MonteCarloError(f"run {run} drew an impossible airframe ({exc}); bound that "
                              "dispersion (uniform or truncnormal)") from None


def _gusts(dispersions: Dispersions, seed: int, run: int, n: int, dt: float, speed: float,
           intensity: float, airframe: Airframe) -> np.ndarray | None:
    if not dispersions.has_gusts or intensity <= 0:
        return None
    from uavdyn.emulation import dryden_gusts, gust_span

    rng = np.random.default_rng([seed, run, 1])
    return dryden_gusts(rng, n, dt, max(speed, 5.0), intensity, wingspan=gust_span(airframe),
                        **dispersions.gust_scales)


def fly_controlled_runs(controller: Controller, nominal: Airframe, dispersions: Dispersions,
                        scenario: Scenario, runs: int, seed: int = 0,
                        altitude: float = 100.0, airspeed: float | None = None,
                        first: int = 0) -> ControlledRuns:
    """Fly ``runs`` dispersed airframes through ``scenario`` with ``controller`` in the loop.

    Parameters
    ----------
    controller : Controller
        The MPC (reset before each run; it predicts with its own model), or anything with its
        interface (:mod:`uavdyn.montecarlo.controllers`: the LQR, the C MPC).
    nominal : Airframe
        The airframe the dispersions apply to (the plant before dispersion).
    dispersions : Dispersions
        What each run draws (:func:`uavdyn.montecarlo.load_dispersions`); limits are not used.
    scenario : Scenario
        References and weights (:func:`uavdyn.mpc.scenario`).
    runs, seed : int
        ``runs`` runs of study seed ``seed``.
    altitude : float
        Start altitude (m).
    airspeed : float, optional
        Nominal trim airspeed before dispersion (default the airframe's).
    first : int
        The first run's number (a chunk of a study: runs ``first..first+runs-1``).

    Returns
    -------
    ControlledRuns

    Raises
    ------
    MonteCarloError
        If a run draws an impossible airframe or the controller is of another kind.
    """
    if controller.kind != nominal.kind:
        raise MonteCarloError(f"the controller is for a {controller.kind}, the airframe a "
                              f"{nominal.kind}")
    dt = controller.config.dt
    n = int(round(scenario.duration / dt))
    drawn = dispersions.column_names()
    columns = OUTCOMES + tuple(drawn)
    table = np.full((runs, len(columns)), np.nan)
    for i, run in enumerate(range(first, first + runs)):
        draw = dispersions.sample(seed, run)
        airframe = _run_airframe(nominal, dispersions, draw, run)
        values = dict(draw.offsets)
        values.update({f"params.{k}": float(v) for k, v in
                       zip(airframe.param_names, airframe.p) if f"params.{k}" in values})
        row = table[i]
        row[0] = run
        row[len(OUTCOMES):] = [values[c] for c in drawn]
        speed = airspeed if airspeed is not None else airframe.nominal_airspeed
        if "airspeed" in dispersions.trim:
            speed = dispersions.trim["airspeed"].apply(speed, draw.offsets["trim.airspeed"])
        try:
            point = trim(airframe, speed)
        except TrimError:
            row[1] = 0.0
            continue
        row[1] = 1.0
        row[2:len(OUTCOMES)] = _fly(controller, airframe, dispersions, scenario, seed, run, n,
                                    point, draw, altitude, speed)
    return ControlledRuns(columns, table, _drivers(columns, table, drawn), scenario.name)


def _fly(controller, airframe, dispersions, scenario, seed, run, n, point, draw, altitude,
         speed) -> np.ndarray:
    """One run's outcomes ``departed .. median_solve_ms`` (:data:`OUTCOMES`)."""
    x0 = np.array(trim_state(airframe, point), float)
    for name, dist in dispersions.initial.items():
        i = STATE_KEYS.index(name)
        x0[i] = dist.apply(x0[i], draw.offsets[f"initial.{name}"])
    gusts = _gusts(dispersions, seed, run, n, controller.config.dt, speed,
                   draw.gust_intensity, airframe)
    plant = gusty_plant(airframe, controller.config.dt, gusts)
    v0 = (float(np.hypot(point.x[0], point.x[1])) if airframe.kind == "fixed_wing"
          else float(point.x[0]))
    refs = scenario.references(float(point.x[3]), altitude, v0)
    with np.errstate(all="ignore"):
        res = fly_closed_loop(controller, plant, np.r_[x0, altitude], point.u, n, *refs,
                              scenario.weights)
    departed = res.departure is not None
    counts = res.counts()
    ok = res.solve_times_s[res.success] if np.any(res.success) else np.array([np.nan])
    rmse = np.nan if departed else res.rmse(scenario.tracked, scenario.start)
    pitch_error = np.max(np.abs(res.states[1:, 3] - res.theta_ref)) if len(res.theta_ref) \
        else 0.0
    bound, rate = limit_activity(controller, res.controls, point.u)
    return np.array([float(departed), rmse, float(np.degrees(pitch_error)),
                     float(np.degrees(np.max(np.abs(res.states[:, 3])))), bound, rate,
                     float(np.sum(~res.success)), float(counts["shifted"] + counts["held"]),
                     float(np.median(ok) * 1e3)])


def limit_activity(controller, controls: np.ndarray, u0) -> tuple[float, float]:
    """Shares of the intervals with a control on its bound and with a control changed by its
    rate limit's step (within :data:`ACTIVE_TOLERANCE`), ``u0`` the command before the first.
    """
    if not len(controls):
        return 0.0, 0.0
    lo, hi = controller.bounds[:, 0], controller.bounds[:, 1]
    tol = ACTIVE_TOLERANCE * (hi - lo)
    on_bound = np.any((controls <= lo + tol) | (controls >= hi - tol), axis=1)
    step = np.abs(np.diff(np.vstack([np.asarray(u0, float)[None, :], controls]), axis=0))
    limit = controller.rates * controller.config.dt
    on_rate = np.any(step >= limit * (1 - ACTIVE_TOLERANCE), axis=1)
    return float(np.mean(on_bound)), float(np.mean(on_rate))


def _badness(result: ControlledRuns) -> np.ndarray:
    """Tracking error with departed and untrimmed runs worst."""
    err = result.column("tracking_rmse").copy()
    err[~np.isfinite(err)] = np.inf
    return err


def _n_worst(n: int) -> int:
    return max(1, int(round(WORST_SHARE * n)))


def _drivers(columns: tuple[str, ...], table: np.ndarray, drawn: list[str]) -> list[Driver]:
    bad = table[:, columns.index("tracking_rmse")].copy()
    bad[~np.isfinite(bad)] = np.inf
    rank = np.argsort(np.argsort(bad, kind="stable"), kind="stable").astype(float)
    worst = np.argsort(-bad, kind="stable")[:_n_worst(len(bad))]
    out = []
    for name in drawn:
        v = table[:, columns.index(name)]
        sd = float(np.std(v))
        if not sd > 0 or len(v) < 3:
            out.append(Driver(name, float("nan"), float("nan"), 0.0))
            continue
        rho = float(spearmanr(v, rank).statistic)
        out.append(Driver(name, _explained(v, rank), rho,
                          float((np.mean(v[worst]) - np.mean(v)) / sd)))
    return sorted(out, key=lambda d: -d.explained if np.isfinite(d.explained) else 1.0)


def _explained(v: np.ndarray, y: np.ndarray) -> float:
    """Correlation ratio: the share of the variance of ``y`` between the quartiles (halves
    below 8 values) of ``v``."""
    k = 4 if len(v) >= 8 else 2
    group = np.searchsorted(np.quantile(v, np.linspace(0, 1, k + 1)[1:-1]), v, side="right")
    total = float(np.sum((y - y.mean()) ** 2))
    between = sum(np.sum(group == g) * (y[group == g].mean() - y.mean()) ** 2
                  for g in range(k) if np.any(group == g))
    return float(between / total) if total > 0 else float("nan")


def describe(result: ControlledRuns) -> list[str]:
    """Summary lines: runs, departures, failed solves, tracking error spread, the drivers."""
    err = result.column("tracking_rmse")
    ok = err[np.isfinite(err)]
    lines = [f"{len(err)} runs of the {result.scenario}: "
             f"{int(np.nansum(result.column('departed')))} departed, "
             f"{int(np.sum(result.column('trim_ok') == 0))} did not trim, "
             f"{int(np.nansum(result.column('failed_solves')))} failed solves, "
             f"{int(np.nansum(result.column('fallbacks')))} fallbacks; controls on a bound "
             f"{np.nanmean(result.column('bound_share')):.1%}, on a rate limit "
             f"{np.nanmean(result.column('rate_share')):.1%} of the intervals (mean)"]
    if len(ok):
        worst = result.worst_runs()
        shown = ", ".join(map(str, worst[:SHOWN_WORST]))
        more = f" of the {len(worst)} worst" if len(worst) > SHOWN_WORST else " worst"
        lines.append(f"tracking RMSE median {np.median(ok):.4g}, worst {np.max(ok):.4g} "
                     f"(runs {shown}{more})")
    lines += [f"{d.column}: explains {d.explained:.0%} of the error ranks, rank correlation "
              f"{d.spearman:+.2f}, worst runs {d.worst_shift_sd:+.2f} sd"
              for d in result.drivers]
    return lines


__all__ = ["OUTCOMES", "ControlledRuns", "Driver", "describe", "fly_controlled_runs",
           "gusty_plant", "limit_activity"]
