"""The stated state feedback a closed-loop Monte Carlo flies: an LQR on the body states about
the nominal trim, weighted by Bryson's rule."""

from __future__ import annotations

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.linear import linearise
from uavdyn.montecarlo.errors import MonteCarloError

# Bryson's rule for the closed-loop studies' LQR: the largest deviation the loop should
# tolerate of u, w (m/s), q (rad/s), theta (rad), and the share of each control's half travel
LQR_MAX_DEVIATION = (2.0, 2.0, 0.5, 0.1)
LQR_CONTROL_SHARE = 0.5


def lqr_gain(airframe: Airframe, point) -> np.ndarray:
    """The gain ``K`` (``nu x 4``) of a continuous LQR on the body states ``u, w, q, theta``
    linearised at ``point`` (actuator lags left out), weighted by Bryson's rule
    (:data:`LQR_MAX_DEVIATION`; each control up to :data:`LQR_CONTROL_SHARE` of its half
    travel): the stated feedback a closed-loop study flies each run with.

    Raises
    ------
    MonteCarloError
        If the linearised airframe cannot be stabilised from its controls.
    """
    import control

    A, B = linearise(airframe, point, actuators=False)
    half = np.array([(hi - lo) / 2 for lo, hi in airframe.control_bounds()])
    Q = np.diag(1.0 / np.square(LQR_MAX_DEVIATION))
    R = np.diag(1.0 / np.square(LQR_CONTROL_SHARE * half))
    try:
        K, _, _ = control.lqr(A, B, Q, R)
    except Exception as exc:  # python-control raises its own types for an unsolvable Riccati
        raise MonteCarloError(f"no LQR for airframe '{airframe.name}' at its trim: "
                              f"{' '.join(str(exc).split())}") from None
    return np.asarray(K, float)


__all__ = ["LQR_CONTROL_SHARE", "LQR_MAX_DEVIATION", "lqr_gain"]
