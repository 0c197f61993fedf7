"""Speed against acceleration: a logged velocity in the wrong unit (km/h, knots) is refused.

The pitch-plane check (:func:`uavdyn.flightdata.checks.check_kinematics`) catches pitch in the
wrong unit; nothing in the attitude catches a speed multiplied by 3.6. The accelerometer does:
in body axes (FRD) the velocity obeys

    du/dt = f_x - g sin(theta)                    + r v - q w
    dw/dt = f_z + g cos(theta) cos(phi)           + q u - p v

with ``f`` the accelerometer's specific force. The relation holds for ground-relative
velocities and for air-relative ones in a steady wind (the wind's inertial derivative is zero);
gusts and sensor noise scatter it but do not bias it. Over windows of
:data:`SPEED_WINDOW_S` the change of the logged speed less the integrated kinematic terms is
fitted against the integrated specific-force-plus-gravity term through the origin: the slope
is the factor the speed is scaled by (1 for m/s; 3.6 for km/h, 1.94 for knots, 3.28 for
ft/s). A slope outside :data:`SCALE_LIMITS` that is also :data:`SCALE_SIGNIFICANCE` standard
errors away from 1 is refused; a flight with too little speed change to tell (hover, steady
cruise) is passed, with the fit recorded.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uavdyn.flightdata.errors import FlightDataError

G = 9.80665
SPEED_WINDOW_S = 2.0         # long enough to integrate over accelerometer noise, short
                             # enough that a gyro or accelerometer bias adds < ~0.2 m/s
SCALE_LIMITS = (1 / 1.6, 1.6)  # an airspeed calibration error of tens of percent passes;
                               # knots (1.94), mph (2.24), ft/s (3.28), km/h (3.6) do not
SCALE_SIGNIFICANCE = 5.0     # standard errors of the slope away from 1 before refusing
MIN_WINDOWS = 5


def _window_integrals(time: np.ndarray, values: np.ndarray, width: int
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Per non-overlapping window of ``width`` intervals: the trapezoid integral of each column
    of ``values`` and whether every sample in the window is finite."""
    n = len(time)
    starts = np.arange(0, n - width, width)
    pair = 0.5 * (values[1:] + values[:-1]) * np.diff(time)[:, None]
    cum = np.vstack([np.zeros(values.shape[1]), np.cumsum(np.nan_to_num(pair), axis=0)])
    bad = np.concatenate([[0], np.cumsum(~np.all(np.isfinite(values), axis=1))])
    ends = starts + width
    ok = (bad[ends + 1] - bad[starts]) == 0
    return cum[ends] - cum[starts], ok


def speed_scales(time: np.ndarray, channels: dict[str, np.ndarray], specific_force: np.ndarray,
                 window_s: float = SPEED_WINDOW_S) -> dict[str, tuple[float, float, int]]:
    """The factor each of ``u`` and ``w`` looks scaled by, against the accelerometer.

    Both are fitted together (weighted least squares over the windows of both equations):
    ``q w`` enters the ``u`` equation and ``q u`` the ``w`` one, so a scaled ``u`` alone also
    upsets the ``w`` balance, and only a joint fit names the right channel. ``v`` is taken
    as logged (its terms are small in longitudinal flight).

    Parameters
    ----------
    time : ndarray
        Uniform grid (s).
    channels : dict of str to ndarray
        ``roll, pitch, p, q, r, u, v, w`` on the grid (rad, rad/s, m/s; NaN in gaps).
    specific_force : ndarray
        ``N x 3`` accelerometer specific force in body axes FRD (m/s^2; ``-g`` on z at rest).
    window_s : float
        Window length (s).

    Returns
    -------
    dict
        ``{'u': (scale, standard error, windows), 'w': ...}``; NaN where fewer than
        :data:`MIN_WINDOWS` windows are usable or the flight does not excite the fit.
    """
    c = channels
    none = {k: (float("nan"), float("nan"), 0) for k in ("u", "w")}
    width = max(1, int(round(window_s / float(np.median(np.diff(time))))))
    if len(time) <= width:
        return none
    terms = np.column_stack([
        specific_force[:, 0] - G * np.sin(c["pitch"]) + c["r"] * c["v"],
        c["q"] * c["w"],
        specific_force[:, 2] + G * np.cos(c["pitch"]) * np.cos(c["roll"]) - c["p"] * c["v"],
        c["q"] * c["u"], c["u"], c["w"]])
    integral, ok = _window_integrals(time, terms, width)
    starts = np.arange(0, len(time) - width, width)
    m = int(ok.sum())
    if m < MIN_WINDOWS:
        return {k: (float("nan"), float("nan"), m) for k in ("u", "w")}
    du = (c["u"][starts + width] - c["u"][starts])[ok]
    dw = (c["w"][starts + width] - c["w"][starts])[ok]
    i = integral[ok]
    # unknowns a_u, a_w (true = logged x a):  a_u du + a_w I(qw) = I(fx - g s + rv)
    #                                         a_w dw - a_u I(qu) = I(fz + g c c - pv)
    rows = np.vstack([np.column_stack([du, i[:, 1]]), np.column_stack([-i[:, 3], dw])])
    rhs = np.concatenate([i[:, 0], i[:, 2]])
    weight = np.ones(2 * m)
    for _ in range(2):   # reweight each equation by its own residual scatter
        sol, *_ = np.linalg.lstsq(rows * weight[:, None], rhs * weight, rcond=None)
        resid = rhs - rows @ sol
        for part in (slice(0, m), slice(m, 2 * m)):
            weight[part] = 1.0 / max(float(np.std(resid[part])), 1e-9)
    normal = (rows * weight[:, None]).T @ (rows * weight[:, None])
    if np.linalg.cond(normal) > 1e12 or np.any(sol <= 0):
        return {k: (float("nan"), float("nan"), m) for k in ("u", "w")}
    dof = max(2 * m - 2, 1)
    sigma2 = float(np.sum((weight * resid) ** 2)) / dof
    cov = sigma2 * np.linalg.inv(normal)
    return {k: (float(1.0 / sol[j]), float(np.sqrt(cov[j, j])) / float(sol[j]) ** 2, m)
            for j, k in enumerate(("u", "w"))}


def check_speed_scale(path: str | Path, time: np.ndarray, channels: dict[str, np.ndarray],
                      specific_force: np.ndarray, sources: dict[str, str]) -> dict:
    """Refuse a ``u`` or ``w`` that the accelerometer says is scaled (wrong unit).

    Parameters
    ----------
    path : str or Path
        The log, for the message.
    time, channels, specific_force
        As for :func:`speed_scales`.
    sources : dict of str to str
        The logged field each of ``u`` and ``w`` came from (named in the message).

    Returns
    -------
    dict
        The fit per axis (``scale``, ``standard_error``, ``windows``) for the provenance.

    Raises
    ------
    FlightDataError
        One line naming the log and the channel whose speed looks scaled.
    """
    fits = speed_scales(time, channels, specific_force)
    lo, hi = SCALE_LIMITS
    for axis, (scale, se, windows) in fits.items():
        if not np.isfinite(scale) or lo <= scale <= hi:
            continue
        if abs(scale - 1.0) < SCALE_SIGNIFICANCE * se:
            continue
        raise FlightDataError(
            f"the speed {axis} changes {scale:.3g} times as much as the accelerometer says "
            f"(fit over {windows} windows of {SPEED_WINDOW_S:g} s, standard error {se:.2g}): "
            f"the speed looks scaled (e.g. km/h x 3.6, knots x 1.94 instead of m/s)", path,
            column=sources.get(axis, axis))
    return {axis: {"scale": round(s, 4) if np.isfinite(s) else None,
                   "standard_error": round(e, 4) if np.isfinite(e) else None, "windows": k}
            for axis, (s, e, k) in fits.items()}
