"""Dryden turbulence: the MIL-F-8785C shaping filters and exactly discretised gust samples."""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg

from uavdyn.airframes import Airframe

# Span used for the Dryden pitch-rate gust filter of a multirotor (no wing): the lateral rotor-
# tip-to-tip extent 2 arm cos(45 deg) + D of an X frame, with D the propeller diameter below.
MULTIROTOR_PROP_DIAMETER_M = 0.254  # [EST] 10 in propellers of the F450 class (as v_induced)


def gust_span(airframe: Airframe) -> float:
    """The span ``b`` (m) of the Dryden pitch-rate gust filter for ``airframe``: the wing span
    ``b`` of a fixed wing; for a multirotor the lateral rotor-tip-to-tip extent of an X frame,
    ``2 arm cos(45 deg) + D`` with ``D`` = :data:`MULTIROTOR_PROP_DIAMETER_M` (0.572 m for the
    F450 preset's arm of 0.225 m)."""
    P = airframe.params
    if airframe.kind == "fixed_wing":
        return float(P.b)
    return float(2 * P.arm * math.cos(math.pi / 4) + MULTIROTOR_PROP_DIAMETER_M)


def dryden_filter(airspeed: float, intensity: float = 1.0, wingspan: float = 1.0,
                  sigma_u: float = 1.06, sigma_w: float = 0.7, L_u: float = 200.0,
                  L_w: float = 50.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous state space ``(A, B, C)`` of the Dryden shaping filters driven by white noise
    of two-sided PSD ``pi`` (unit-intensity in the MIL normalisation): states
    ``[x_u, x_w1, x_w2, z_q]``, outputs ``[u_g, w_g, q_g]``, inputs ``[n_u, n_w]``.

    * ``H_u(s) = sigma_u sqrt(2V/(pi L_u)) / (s + V/L_u)``
    * ``H_w(s) = sigma_w sqrt(3V/(pi L_w)) (s + V/(sqrt3 L_w)) / (s + V/L_w)^2`` (controllable
      canonical form, states ``x_w1, x_w2``)
    * ``H_q(s) = -(s/V) / (1 + T s) H_w(s)`` with ``T = 4 b/(pi V)`` (MIL-F-8785C; the span
      ``b`` is ``wingspan``). Sign: Etkin's ``q_g = -d w_g/d x`` makes ``q - q_g`` the
      air-relative pitch rate (a gust field with ``d w_g/d x > 0`` meets the nose with more
      downward air than the tail, as a nose-up rotation would); frozen turbulence flown through
      at ``V`` gives ``d/dx = (1/V) d/dt``. Realised without a derivative: ``s/(1+Ts) =
      (1 - 1/(1+Ts))/T``, so ``q_g = -(w_g - z_q)/(V T)`` with ``T z_q' = w_g - z_q``.
    """
    V = float(airspeed)
    su, sw = sigma_u * intensity, sigma_w * intensity
    a_u, a_w = V / L_u, V / L_w
    k_u = su * math.sqrt(2 * V / (math.pi * L_u))
    k_w = sw * math.sqrt(3 * V / (math.pi * L_w))
    c_w = np.array([k_w * a_w / math.sqrt(3), k_w])  # w_g = c_w . [x_w1, x_w2]
    T = 4 * wingspan / (math.pi * V)
    A = np.zeros((4, 4))
    A[0, 0] = -a_u
    A[1:3, 1:3] = [[0.0, 1.0], [-a_w**2, -2 * a_w]]
    A[3, 1:3], A[3, 3] = c_w / T, -1.0 / T
    B = np.zeros((4, 2))
    B[0, 0], B[2, 1] = 1.0, 1.0
    C = np.zeros((3, 4))
    C[0, 0] = k_u
    C[1, 1:3] = c_w
    C[2, 1:3], C[2, 3] = -c_w / (V * T), 1.0 / (V * T)
    return A, B, C


def dryden_gusts(rng: np.random.Generator, n: int, dt: float, airspeed: float,
                 intensity: float = 1.0, wingspan: float = 1.0,
                 sigma_u: float = 1.06, sigma_w: float = 0.7,
                 L_u: float = 200.0, L_w: float = 50.0) -> np.ndarray:
    """``n x 3`` body-axis gusts ``[u_g, w_g, q_g]`` sampled every ``dt`` from the Dryden
    spectra (MIL-F-8785C forms, :func:`dryden_filter`; default scales are Beard & McLain's
    low-altitude light turbulence, times ``intensity``). The shaping filters are discretised
    exactly (Van Loan) and started in their stationary distribution, so the sampled sequence
    has the continuous spectra's covariance at any ``dt``.

    ``airspeed`` is the frozen-turbulence convection speed, i.e. the airspeed at which the
    vehicle flies through the air mass (for a hovering multirotor use the mean wind speed
    plus a floor). ``wingspan`` (m) sets the pitch-rate gust's extra first-order filter,
    time constant ``4 b/(pi V)``: take it from the airframe (:func:`gust_span`).

    The random stream is drawn so that ``u_g, w_g`` do not depend on ``wingspan``: the
    pitch-rate filter's noise comes after theirs."""
    if n < 1 or not (dt > 0):
        raise ValueError(f"need n >= 1 and dt > 0, got n={n}, dt={dt}")
    if intensity == 0.0:
        return np.zeros((n, 3))
    if intensity < 0 or not (airspeed > 0) or not (wingspan > 0):
        raise ValueError(f"need intensity >= 0, airspeed > 0 and wingspan > 0, got "
                         f"{intensity}, {airspeed}, {wingspan}")
    A, B, C = dryden_filter(airspeed, intensity, wingspan, sigma_u, sigma_w, L_u, L_w)
    # Van Loan: discrete transition and process-noise covariance for white noise of two-sided
    # PSD pi (matching the 1/pi in the gains).
    m = A.shape[0]
    Qc = math.pi * B @ B.T
    F = np.zeros((2 * m, 2 * m))
    F[:m, :m], F[:m, m:], F[m:, m:] = -A, Qc, A.T
    G = scipy.linalg.expm(F * dt)
    Ad = G[m:, m:].T
    Qd = Ad @ G[:m, m:]
    Qd = 0.5 * (Qd + Qd.T)
    L = np.linalg.cholesky(Qd + 1e-15 * np.eye(m))
    # Start in the stationary distribution (solve the discrete Lyapunov equation).
    P0 = scipy.linalg.solve_discrete_lyapunov(Ad, Qd)
    P0 = 0.5 * (P0 + P0.T)
    # Lower-triangular factors and z_q last: the first three states use only the first three
    # normals of each row, drawn in the same order as without the pitch-rate filter.
    e0 = rng.standard_normal(m - 1)
    e = rng.standard_normal((n, m - 1))
    e0 = np.concatenate([e0, rng.standard_normal(1)])
    e = np.hstack([e, rng.standard_normal((n, 1))])
    s = np.linalg.cholesky(P0 + 1e-15 * np.eye(m)) @ e0
    noise = e @ L.T
    out = np.empty((n, 3))
    for k in range(n):
        out[k] = C @ s
        s = Ad @ s + noise[k]
    return out
