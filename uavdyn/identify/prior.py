"""A priori information in an output-error fit: a Gaussian prior on each fitted parameter
around the airframe file's value, the estimate then the maximum a posteriori (Morelli and
Klein, *Aircraft System Identification*, "a priori information"; Jategaonkar's "a priori
values").

The prior of a parameter has the standard deviation ``rel_sd x`` its file value's magnitude.
In the fit's scaled unknowns (``theta = (p - p_file) / scale``) that is ``rel_sd`` for every
parameter, and the prior adds the residual rows ``w_j theta_j`` to the least squares. A
parameter whose file value is 0 has no prior (a flat one): 0 there means "no such term" (no
lag, no alpha-dot moment), not a value known to some relative accuracy, and any absolute
width would be a guess (measured: a prior of 0 +- 0.3 on the trainer's ``C_m_alpha_dot``,
whose emulated truth is -6, pulled every other moment derivative 30 % off); without a prior it
is judged like a data-only estimate (not determined: it keeps the file's 0).

The data rows are weighted as if their residuals were white; real residuals are coloured and
the data then hold less information than the Cramer-Rao bound says (the corrected standard
error is larger, :mod:`uavdyn.identify.uncertainty`). Weighed against the white-residual data,
the prior would count for too little. So its rows carry ``w_j = f_j / rel_sd`` with ``f_j``
the ratio of the corrected to the Cramer-Rao standard error of the data-only fit (at least
1): for one parameter, the maximum a posteriori is then exactly the inverse-variance mean of
the data-only estimate (with its corrected variance) and the prior. The posterior covariance
is ``(C_data^-1 + P^-1)^-1`` with ``C_data`` the corrected covariance of the data at the
estimate, so every posterior standard error is below both the prior's and the data's. Whether
the data determine a parameter is judged on ``C_data`` (its interval spanning zero, collinear
groups) and on the estimate (on a bound); the halves check's flags of the data-only fit are
kept. A parameter still on a bound under the prior keeps the file's value (the others
refitted under the prior, :mod:`uavdyn.identify.fallback`).

The pull of the prior is reported as its share of the information on each parameter at the
estimate, ``1 - var_posterior / var_data`` (0: the data alone set the value, 1: the prior
alone), with the data-only estimate beside the posterior one.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from uavdyn.identify.errors import IdentifyError
from uavdyn.identify.result import Estimate

PRIOR_SD_DEFAULT = 0.3   # relative standard deviation of ``--prior nominal`` without a value


def check_prior_sd(rel_sd: float) -> float:
    """``rel_sd`` as a float, refused unless finite and > 0."""
    if isinstance(rel_sd, bool) or not isinstance(rel_sd, (int, float)) \
            or not math.isfinite(rel_sd) or rel_sd <= 0:
        raise IdentifyError(f"the prior's relative standard deviation must be a finite "
                            f"number > 0, got {rel_sd!r}")
    return float(rel_sd)


def prior_precision(file_values: np.ndarray, rel_sd: float) -> np.ndarray:
    """The prior's precision on each scaled unknown: ``1 / rel_sd^2``, 0 (no prior) where the
    file value is 0."""
    return np.where(np.asarray(file_values) != 0, 1.0 / rel_sd**2, 0.0)


def prior_weights(std_corrected: np.ndarray, std_cramer_rao: np.ndarray,
                  precision: np.ndarray) -> np.ndarray:
    """The prior rows' weights ``f_j / rel_sd`` in the scaled unknowns (module docstring)."""
    f = np.maximum(np.asarray(std_corrected) / np.maximum(np.asarray(std_cramer_rao), 1e-300),
                   1.0)
    return f * np.sqrt(precision)


def posterior(cov_data: np.ndarray, precision: np.ndarray) -> np.ndarray:
    """``(C_data^-1 + P^-1)^-1`` with ``P^-1 = diag(precision)``: the covariance of the
    scaled unknowns with the prior."""
    info = np.linalg.pinv(cov_data, hermitian=True) + np.diag(precision)
    cov = np.linalg.inv(info)
    return 0.5 * (cov + cov.T)


def prior_share(cov_data: np.ndarray, cov_posterior: np.ndarray) -> np.ndarray:
    """Each parameter's prior share of the information, ``1 - var_posterior / var_data``
    (both at the estimate; in [0, 1])."""
    var_data = np.maximum(np.diag(cov_data), 1e-300)
    return np.clip(1.0 - np.diag(cov_posterior) / var_data, 0.0, 1.0)


def with_data_verdicts(posterior_estimates: list[Estimate], data_estimates: list[Estimate]
                       ) -> list[Estimate]:
    """The posterior estimates with the data-only estimate beside each, and the data-only
    fit's flags that are not about the estimate's interval (the halves of the data
    disagreeing: a flag on the model structure) added to its own."""
    data = {e.name: e for e in data_estimates}
    out = []
    for e in posterior_estimates:
        d = data.get(e.name)
        if d is None or e.searched:
            out.append(e)
            continue
        extra = tuple(w for w in d.undetermined if "halves" in w and w not in e.undetermined)
        out.append(dataclasses.replace(e, undetermined=e.undetermined + extra,
                                       excitation=e.excitation or d.excitation,
                                       data_value=d.value))
    return out
