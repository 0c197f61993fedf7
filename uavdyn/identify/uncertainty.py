"""Uncertainty of output-error estimates that a flight-test engineer can use.

The Cramer-Rao bound ``M^-1`` (``M = J^T J`` of the noise-weighted residuals) assumes white
residuals. Residuals of a fit to real or richer-than-the-model data are coloured (model error
drifts over a window), and the bound is then far too small. The corrected covariance (Morelli
and Klein, *Aircraft System Identification*, the residual-autocorrelation correction of the
output-error covariance) is

    Cov = M^-1 [ sum_i sum_j S_i^T R(i - j) S_j ] M^-1

with ``S_i`` the sensitivities at sample ``i`` and ``R(k)`` the residuals' estimated
autocovariance at lag ``k`` (a 4 x 4 matrix over the body states). Here each record is one
window restarted from a recorded state: the double sum runs over the samples of each window
(the restart cuts the drift), with ``R`` estimated from all windows. With white residuals it
equals the Cramer-Rao bound. A second estimate, sortie by sortie (a cluster-robust sandwich: how far
the sorties' own gradients pull the estimate apart), also holds a structure error that biases
the estimate differently on different manoeuvres; each parameter's corrected variance is the
larger of the two. The windows' start states are estimated too (nuisance unknowns):
they are profiled out exactly (Schur complement), so the figures are those of the parameters
with every start state free.

Collinearity (Belsley, Kuh and Welsch): condition indices of the column-scaled information
matrix and the variance-decomposition proportions name the groups of parameters the data
cannot separate (a condition index above :data:`CONDITION_FLAG` with two or more parameters
carrying more than :data:`PROPORTION_FLAG` of their variance on it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uavdyn.identify.errors import IdentifyError

N_BODY = 4
CONDITION_FLAG = 30.0   # Belsley's threshold for a strong near-dependency
PROPORTION_FLAG = 0.5   # share of a parameter's variance on one near-dependency
SPANS_ZERO = 2.0        # an interval of this many corrected standard errors containing 0


@dataclass(frozen=True)
class Uncertainty:
    """Covariances of the scaled unknowns and what the data cannot separate.

    Attributes
    ----------
    cramer_rao : ndarray
        ``M^-1``: white residuals assumed.
    corrected : ndarray
        Corrected for the residuals' autocorrelation within each window, and (with three or
        more sorties) each variance at least the between-sortie one.
    residual_sigma : ndarray
        Per body state, the RMS of the (noise-weighted) residuals.
    correlation_time_s : ndarray
        Per body state, the lag at which the residual autocorrelation first falls below 1/e
        (0 for white residuals): how coloured the residuals are.
    condition_indices : ndarray
        Of the column-scaled information matrix, one per near-dependency (ascending).
    variance_proportions : ndarray
        ``[k, j]``: the share of parameter ``j``'s variance on dependency ``k``.
    collinear_groups : list of list of int
        The parameters (indices) of each strong near-dependency.
    weak_directions : ndarray
        One unit row per group: the combination of the scaled unknowns the data cannot
        determine (:func:`near_dependencies`).
    """

    cramer_rao: np.ndarray
    corrected: np.ndarray
    residual_sigma: np.ndarray
    correlation_time_s: np.ndarray
    condition_indices: np.ndarray
    variance_proportions: np.ndarray
    collinear_groups: list[list[int]]
    weak_directions: np.ndarray

    def diagnostics(self, names: list[str], std: np.ndarray, std_corrected: np.ndarray
                    ) -> dict:
        """The result's ``diagnostics`` record: condition indices, variance proportions,
        collinear groups by name, residual correlation times, corrected / Cramer-Rao ratios."""
        return {
            "condition_indices": self.condition_indices.tolist(),
            "variance_proportions": self.variance_proportions.tolist(),
            "collinear_groups": [[names[j] for j in g] for g in self.collinear_groups],
            "residual_correlation_time_s": dict(zip(("u", "w", "q", "theta"),
                                                    self.correlation_time_s.tolist())),
            "corrected_over_cramer_rao": dict(zip(names, (std_corrected / np.maximum(
                std, 1e-300)).tolist()))}


def estimate_uncertainty(J, r: np.ndarray, n_theta: int, n_windows: int, length: int,
                         estimate_x0: bool, interval: float,
                         sortie_of_window: np.ndarray | None = None) -> Uncertainty:
    """The Cramer-Rao and corrected covariances of the first ``n_theta`` unknowns.

    Parameters
    ----------
    J : scipy.sparse matrix
        Jacobian of the residual ``r`` with respect to ``z = [theta; dx]``.
    r : ndarray
        Residuals: ``4 * length * n_windows`` data rows (sample-major, the body states per
        sample, window after window), then ``4 * n_windows`` rows of the start-state prior
        (when ``estimate_x0``), already in units of their noise.
    n_theta, n_windows, length : int
        Parameters, windows and samples per window.
    estimate_x0 : bool
        Whether the windows' start states are unknowns (columns after ``theta``).
    interval : float
        Sample interval (s), for the correlation times.
    sortie_of_window : ndarray, optional
        The sortie of each window: with three or more sorties the corrected covariance is also
        estimated sortie by sortie (:func:`_between_sorties`), and each parameter's corrected
        variance is the larger of the two.

    Raises
    ------
    IdentifyError
        If the information matrix is singular (the data cannot tell the parameters apart).
    """
    n_data = N_BODY * length * n_windows
    resid = r[:n_data].reshape(n_windows, length, N_BODY)
    sigma = np.sqrt(np.mean(resid**2, axis=(0, 1)))
    scale = 1.0 / np.maximum(sigma, 1e-300)  # data rows in units of their own residual RMS
    A, extra, M = information(J, scale, n_theta, n_windows, length, estimate_x0)
    M_inv = _inverse(M)
    v = resid * scale
    R = _autocovariance(v)
    T = _block_toeplitz(R)
    B = np.einsum("wia,ij,wjb->ab", A, T, A, optimize=True) + extra
    corrected = M_inv @ B @ M_inv
    between = None
    if sortie_of_window is not None and len(np.unique(sortie_of_window)) >= 3:
        between = M_inv @ _between_sorties(A, v, sortie_of_window) @ M_inv
        corrected = _larger_variances(corrected, between)
    conditions, proportions, groups, weak = near_dependencies(M)
    return Uncertainty(cramer_rao=M_inv, corrected=0.5 * (corrected + corrected.T),
                       residual_sigma=sigma, correlation_time_s=_correlation_time(R, interval),
                       condition_indices=conditions, variance_proportions=proportions,
                       collinear_groups=groups, weak_directions=weak)


def information(J, scale: np.ndarray, n_theta: int, n_windows: int, length: int,
                estimate_x0: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The parameters' sensitivities ``A`` (``W x 4L x n_theta``, data rows times ``scale``
    per body state, start states profiled out), the start-state prior's share ``extra`` and
    the information matrix ``M = sum A^T A + extra`` of the first ``n_theta`` unknowns (the
    Cramer-Rao bound is ``M^-1`` when ``scale`` is one over the white noise's standard
    deviation per state). Arguments as :func:`estimate_uncertainty`."""
    n_data = N_BODY * length * n_windows
    J = J.tocsr()
    A = np.asarray(J[:n_data, :n_theta].todense()).reshape(n_windows, length * N_BODY, n_theta)
    A = A * np.tile(scale, length)[None, :, None]
    if estimate_x0:
        A, extra = _profile_start_states(J, A, scale, n_theta, n_windows, length)
    else:
        extra = np.zeros((n_theta, n_theta))
    M = np.einsum("wia,wib->ab", A, A) + extra  # the Schur complement of the start states
    return A, extra, M


def _inverse(M: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.inv(M)
    except np.linalg.LinAlgError:
        raise IdentifyError("the data cannot tell the parameters apart (singular information "
                            "matrix): fit fewer of them") from None


def _between_sorties(A: np.ndarray, v: np.ndarray, sortie_of_window: np.ndarray
                     ) -> np.ndarray:
    """The score's covariance from how the sorties pull the estimate apart: ``S/(S-1) sum_s
    g_s g_s^T`` with ``g_s`` the gradient of sortie ``s``'s windows (a cluster-robust
    sandwich). It also holds what no residual model does: a structure error that biases the
    estimate differently on different manoeuvres."""
    g = np.einsum("wia,wi->wa", A, v.reshape(v.shape[0], -1))
    sorties = np.unique(sortie_of_window)
    G = np.array([g[sortie_of_window == s].sum(axis=0) for s in sorties])
    G -= G.mean(axis=0)
    n = len(sorties)
    return n / (n - 1) * G.T @ G


def _larger_variances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A covariance with each variance the larger of ``a``'s and ``b``'s, and ``a``'s
    correlations (a conservative combination of two estimates of one covariance)."""
    da, db = np.sqrt(np.maximum(np.diag(a), 0.0)), np.sqrt(np.maximum(np.diag(b), 0.0))
    d = np.maximum(da, db)
    corr = a / np.outer(np.maximum(da, 1e-300), np.maximum(da, 1e-300))
    return corr * np.outer(d, d)


def _profile_start_states(J, A: np.ndarray, scale: np.ndarray, n_theta: int, n_windows: int,
                          length: int) -> tuple[np.ndarray, np.ndarray]:
    """The parameters' sensitivities with each window's start state profiled out, and the
    (white, unit-variance) contribution of the start-state prior rows to the corrected
    information: ``A_w - B_w (B_w^T B_w + I)^-1 B_w^T A_w`` per window, where ``B_w`` is the
    window's sensitivity to its own start state."""
    n_data = N_BODY * length * n_windows
    rows = length * N_BODY
    out = np.empty_like(A)
    extra = np.zeros((n_theta, n_theta))
    row_scale = np.tile(scale, length)[:, None]
    for w in range(n_windows):
        cols = slice(n_theta + N_BODY * w, n_theta + N_BODY * (w + 1))
        Bw = np.asarray(J[w * rows:(w + 1) * rows, cols].todense()) * row_scale
        prior = np.asarray(J[n_data + N_BODY * w:n_data + N_BODY * (w + 1), cols].todense())
        Mxx = Bw.T @ Bw + prior.T @ prior
        G = np.linalg.solve(Mxx, Bw.T @ A[w])  # how the start state absorbs theta's effect
        out[w] = A[w] - Bw @ G
        extra += (prior @ G).T @ (prior @ G)
    return out, extra


def _autocovariance(v: np.ndarray) -> np.ndarray:
    """``R[k] = E[v_i v_{i+k}^T]`` (``k = 0..L-1``), the biased estimate over all windows
    ``v (W, L, 4)`` (positive semidefinite as a Toeplitz matrix)."""
    W, L, n = v.shape
    R = np.empty((L, n, n))
    for k in range(L):
        R[k] = np.einsum("wis,wit->st", v[:, :L - k], v[:, k:]) / (W * L)
    return R


def _block_toeplitz(R: np.ndarray) -> np.ndarray:
    """The ``4L x 4L`` covariance of one window's residuals (sample-major rows)."""
    L, n, _ = R.shape
    T = np.empty((L, n, L, n))
    for i in range(L):
        for j in range(L):
            T[i, :, j, :] = R[j - i] if j >= i else R[i - j].T
    return T.reshape(L * n, L * n)


def _correlation_time(R: np.ndarray, interval: float) -> np.ndarray:
    """Per state, the first lag where the autocorrelation falls below 1/e (s)."""
    out = np.empty(R.shape[1])
    for s in range(R.shape[1]):
        rho = R[:, s, s] / max(R[0, s, s], 1e-300)
        below = np.flatnonzero(rho < np.exp(-1.0))
        out[s] = (below[0] if len(below) else len(rho)) * interval
    return out


def collinearity(M: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[list[int]]]:
    """Belsley's diagnostics of an information matrix ``M``: condition indices (ascending),
    variance-decomposition proportions ``[k, j]`` and the strong near-dependencies' parameter
    groups (index above :data:`CONDITION_FLAG`, two or more parameters above
    :data:`PROPORTION_FLAG`)."""
    index, proportions, groups, _ = near_dependencies(M)
    return index, proportions, groups


def near_dependencies(M: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, list[list[int]], np.ndarray]:
    """:func:`collinearity` and the strong near-dependencies' directions: one row ``a`` per
    group (unit length), in the unknowns of ``M``, along which the data hold almost no
    information (``a^T M a`` tiny): the combination ``a . theta`` the data cannot determine."""
    d = 1.0 / np.sqrt(np.maximum(np.diag(M), 1e-300))
    S = M * np.outer(d, d)  # unit-length columns
    lam, V = np.linalg.eigh(S)
    lam = np.maximum(lam, 1e-300)
    index = np.sqrt(lam.max() / lam)
    phi = V**2 / lam[None, :]  # [j, k]
    proportions = (phi / phi.sum(axis=1, keepdims=True)).T  # [k, j]
    order = np.argsort(index)
    index, proportions, V = index[order], proportions[order], V[:, order]
    groups, rows = [], []
    for k in range(len(index)):
        members = [int(j) for j in np.flatnonzero(proportions[k] > PROPORTION_FLAG)]
        if index[k] > CONDITION_FLAG and len(members) >= 2:
            groups.append(members)
            a = V[:, k] / d  # v . (theta / d) = 0 in the unknowns themselves
            rows.append(a / np.linalg.norm(a))
    return index, proportions, groups, np.array(rows).reshape(len(rows), len(d))


def constrained(cov: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The covariance ``cov`` of an estimate constrained to ``rows @ theta = 0``:
    ``C - C A^T (A C A^T)^-1 A C`` (no variance left along the rows)."""
    CA = cov @ rows.T
    out = cov - CA @ np.linalg.solve(rows @ CA, CA.T)
    out = 0.5 * (out + out.T)
    out[np.diag_indices_from(out)] = np.maximum(np.diag(out), 0.0)
    return out


def physical_combination(row: np.ndarray, names: list[str], scale: np.ndarray
                         ) -> dict[str, float]:
    """A combination of the scaled unknowns (``theta = (p - p_file) / scale``) as
    ``{name: c}`` on the parameters' changes from the file, ``sum c (p - p_file)``; the
    largest scaled coefficient 1, coefficients below 1e-3 of it left out."""
    row = np.asarray(row, float) / max(float(np.max(np.abs(row))), 1e-300)
    return {n: float(a / s) for n, a, s in zip(names, row, scale) if abs(a) >= 1e-3}


def zero_spanned(value: float, std_c: float) -> str:
    """Why an estimate is not distinguishable from zero (empty when it is)."""
    if abs(value) < SPANS_ZERO * std_c:
        return f"its +-{SPANS_ZERO:g} corrected standard-error interval spans zero"
    return ""


def undetermined(name: str, value: float, std_c: float, groups: list[list[str]]
                  ) -> tuple[tuple[str, ...], list[str]]:
    """Why the data do not determine a parameter (its corrected interval spans zero; it is in
    a collinear group), and the group."""
    why = [zero_spanned(value, std_c)] if zero_spanned(value, std_c) else []
    group = next((g for g in groups if name in g), [])
    if group:
        why.append(f"collinear with {', '.join(g for g in group if g != name)} (these data "
                   "cannot separate them)")
    return tuple(why), group
