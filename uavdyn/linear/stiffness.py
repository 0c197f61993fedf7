"""Whether one explicit RK4 step per log sample can carry a model: a mode the continuous model
damps (``Re lambda < 0``) grows in the RK4 step when ``lambda dt`` leaves RK4's stability
region (``|R(z)| > 1``, ``R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24`` for RK4; on the negative
real axis beyond ``z = -2.785``). A fit may produce such a model (a damping derivative that absorbs
an unmodelled lag, fitted with sub-steps); the commands that step once per sample (``train``,
``mpc``, ``export-c``) then diverge, so the fit and the trainer say so, with the step it needs.
Actuator lags are integrated exactly (:mod:`uavdyn.integrate.augmented`): only the body's
modes count."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavdyn.airframes import Airframe
from uavdyn.integrate.tableau import RK4, explicit_rk_step
from uavdyn.linear.modes import linearise
from uavdyn.linear.trim import TrimError, TrimPoint, trim


def rk4_amplification(z: complex) -> float:
    """``|R(z)|``, the RK4 step's amplification of the mode ``z = lambda dt``: the project's own
    step (:func:`uavdyn.integrate.explicit_rk_step`) applied to ``y' = z y`` over a unit step."""
    return abs(explicit_rk_step(RK4, lambda y: z * y, 1.0 + 0j, 1.0))


def largest_stable_step(eigenvalue: complex) -> float:
    """The largest ``dt`` at which RK4 keeps a damped mode ``eigenvalue`` from growing (the
    boundary of the stability region along the ray ``eigenvalue * dt``, by bisection)."""
    if eigenvalue.real >= 0 or eigenvalue == 0:
        return math.inf
    low, high = 0.0, 3.0 / abs(eigenvalue)  # the region lies inside |z| < 2.9
    for _ in range(60):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if rk4_amplification(eigenvalue * mid) <= 1.0 else (low, mid)
    return low


@dataclass(frozen=True)
class StepStiffness:
    """The body's modes at a trim point against one RK4 step of ``dt``.

    Attributes
    ----------
    dt : float
        The step asked about (s).
    eigenvalues : tuple of complex
        The body's continuous-time eigenvalues (1/s).
    max_stable_dt : float
        The largest step that keeps every damped mode from growing (s).
    point : str
        The trim point, described.
    """

    dt: float
    eigenvalues: tuple[complex, ...]
    max_stable_dt: float
    point: str

    @property
    def too_stiff(self) -> bool:
        """Whether a mode the model damps grows in one RK4 step of ``dt``."""
        return self.dt > self.max_stable_dt

    @property
    def fastest(self) -> complex:
        return max(self.eigenvalues, key=abs)

    def describe(self) -> str:
        lam = self.fastest
        mode = f"{lam.real:.4g}{lam.imag:+.4g}j" if lam.imag else f"{lam.real:.4g}"
        verdict = ("grows in" if self.too_stiff else "stays damped in")
        return (f"its fastest mode ({mode} 1/s at {self.point}) {verdict} one RK4 step of "
                f"{self.dt:g} s (every mode stays damped below {self.max_stable_dt:.3g} s)")


def step_stiffness(airframe: Airframe, dt: float, point: TrimPoint | None = None
                   ) -> StepStiffness | None:
    """:class:`StepStiffness` of ``airframe`` at ``point`` (default: trimmed at its nominal
    airspeed; None when it does not trim there)."""
    if point is None:
        try:
            point = trim(airframe, airframe.nominal_airspeed)
        except TrimError:
            return None
    A, _ = linearise(airframe, point, actuators=False)
    eig = tuple(complex(v) for v in np.linalg.eigvals(A))
    limit = min((largest_stable_step(v) for v in eig), default=math.inf)
    return StepStiffness(float(dt), eig, limit, f"the {point.airspeed:g} m/s trim")
