"""Speed against acceleration: a logged velocity in the wrong unit (km/h, knots) is refused.

The pitch-plane check (:func:`uavdyn.flightdata.checks.check_kinematics`) catches pitch in the
wrong unit; nothing in the attitude catches a speed multiplied by 3.6. The accelerometer does:
in body axes (FRD) the velocity obeys

    du/dt = f_x - g sin(theta)                    + r v - q w
    dw/dt = f_z + g cos(theta) cos(phi)           + q u - p v

with ``f`` the accelerometer's specific force. The relation holds for ground-relative
velocities and for air-relative ones in a steady wind (the wind's inertial derivative is zero);
gusts and sensor noise scatter it but do not bias it. Over windows of
:data:`SPEED_WINDOW_S` the change of the logged ``u`` is fitted against
the integrated specific force, gravity and kinematic terms (:func:`speed_scales`): the fit
is the factor the speed is scaled by (1 for m/s; 3.6 for km/h, 1.94 for knots, 3.28 for
ft/s). A factor of ``u`` outside :data:`SCALE_LIMITS` that is also
:data:`SCALE_SIGNIFICANCE` standard errors away from 1 is refused; a flight with too little
excitation to tell (a hover) is passed, with the fit recorded.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uavdyn.flightdata.errors import FlightDataError

G = 9.80665
SPEED_WINDOW_S = 2.0         # long enough to integrate over accelerometer noise, short
                             # enough that a gyro or accelerometer bias adds < ~0.2 m/s
SCALE_LIMITS = (1 / 1.6, 1.6)  # a pitot calibration error of tens of percent passes;
                               # knots 1.94, mph 2.24, ft/s 3.28, km/h 3.6 do not
SCALE_SIGNIFICANCE = 5.0     # standard errors of the slope away from 1 before refusing
MIN_WINDOWS = 5
FIT_NAMES = ("u", "u_along_x", "u_normal")


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


def _fit(y: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """Least squares through the origin ``y ~ b x``: ``b`` and its standard error (NaN when
    ``x`` is all zero: the flight does not excite the balance)."""
    sxx = float(x @ x)
    if not sxx > 0 or len(y) < 2:
        return float("nan"), float("nan")
    b = float(x @ y) / sxx
    resid = y - b * x
    return b, float(np.sqrt(float(resid @ resid) / (len(y) - 1) / sxx))


def speed_scales(time: np.ndarray, channels: dict[str, np.ndarray], specific_force: np.ndarray,
                 window_s: float = SPEED_WINDOW_S) -> dict[str, tuple[float, float, int]]:
    """The factor the forward speed ``u`` looks scaled by, against the accelerometer.

    With ``I`` the integral over a window, ``u`` is fitted through two balances, each with
    the logged speeds on the measured side (they carry the gusts and noise, so the fit has no
    errors-in-variables bias) and the accelerometer and attitude on the other:

    * along x: ``du + I(q w) - I(r v) = s I(f_x - g sin theta)``;
    * normal to it, where ``q u`` is the centripetal term of a pull-up or a turn:
      ``I(q u) - dw - I(p v) = -s I(f_z + g cos theta cos phi)``;

    and its factor ``s`` is the better determined of the two (a scaled ``w`` or ``v`` alone
    moves these fits only through their small terms, a scaled ``u`` by its whole factor).
    ``w`` is not judged on its own: its balance is the second one read for ``dw``, a
    difference of nearly equal terms.

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
        ``{'u': (scale, standard error, windows)}``, the better of ``'u_along_x'`` and
        ``'u_normal'`` (also returned); NaN where fewer than :data:`MIN_WINDOWS` windows are
        usable or the flight does not excite the balance.
    """
    c = channels
    width = max(1, int(round(window_s / float(np.median(np.diff(time))))))
    nan = (float("nan"), float("nan"))
    if len(time) <= width:
        return {k: (*nan, 0) for k in FIT_NAMES}
    normal = specific_force[:, 2] + G * np.cos(c["pitch"]) * np.cos(c["roll"])
    terms = np.column_stack([specific_force[:, 0] - G * np.sin(c["pitch"]), normal,
                             c["q"] * c["w"] - c["r"] * c["v"],
                             c["q"] * c["u"] - c["p"] * c["v"], c["u"], c["w"]])
    integral, ok = _window_integrals(time, terms, width)
    starts = np.arange(0, len(time) - width, width)[ok]
    m = len(starts)
    if m < MIN_WINDOWS:
        return {k: (*nan, m) for k in FIT_NAMES}
    i = integral[ok]
    du = c["u"][starts + width] - c["u"][starts]
    dw = c["w"][starts + width] - c["w"][starts]
    along, across = _fit(du + i[:, 2], i[:, 0]), _fit(i[:, 3] - dw, -i[:, 1])
    fits = [f for f in (along, across) if np.isfinite(f[1])]
    best = min(fits, key=lambda f: f[1]) if fits else nan
    return {"u": (*best, m), "u_along_x": (*along, m), "u_normal": (*across, m)}


def check_speed_scale(path: str | Path, time: np.ndarray, channels: dict[str, np.ndarray],
                      specific_force: np.ndarray, sources: dict[str, str]) -> dict:
    """Refuse a forward speed ``u`` the accelerometer says is scaled (a wrong unit).

    Parameters
    ----------
    path : str or Path
        The log, for the message.
    time, channels, specific_force
        As for :func:`speed_scales`.
    sources : dict of str to str
        The logged field ``u`` came from (key ``'u'``, named in the message).

    Returns
    -------
    dict
        The fits of :func:`speed_scales` (``scale``, ``standard_error``, ``windows``) for
        the provenance.

    Raises
    ------
    FlightDataError
        One line naming the log and the field ``u`` came from.
    """
    fits = speed_scales(time, channels, specific_force)
    scale, se, windows = fits["u"]
    lo, hi = SCALE_LIMITS
    if np.isfinite(scale) and not lo <= scale <= hi and \
            abs(scale - 1.0) >= SCALE_SIGNIFICANCE * se:
        raise FlightDataError(
            f"the speed u changes {scale:.3g} times as much as the accelerometer says "
            f"(fit over {windows} windows of {SPEED_WINDOW_S:g} s, standard error {se:.2g}): "
            f"the speed looks scaled (e.g. km/h x 3.6, knots x 1.94 instead of m/s)", path,
            column=sources.get("u", "u"))
    return {axis: {"scale": round(s, 4) if np.isfinite(s) else None,
                   "standard_error": round(e, 4) if np.isfinite(e) else None, "windows": k}
            for axis, (s, e, k) in fits.items()}
