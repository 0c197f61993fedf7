"""The learned correction: weight files, the one MLP forward, formulations and the hybrid step.
Training (:mod:`uavdyn.learned.train`, :mod:`uavdyn.learned.torch_model`) needs torch, the
``[train]`` extra, and is imported only when used."""

from uavdyn.learned.formulations import DEFAULT_FORMULATION, FORMULATIONS, Formulation, formulation
from uavdyn.learned.hybrid import (
           hybrid_expression,
           hybrid_jacobian,
           hybrid_step,
           not_kept_reason,
           shipped_correction,
           shipped_corrections,
           shipped_history,
           shipped_identified,
           shipped_weights,
)
from uavdyn.learned.mlp import ACTIVATIONS, mlp_forward
from uavdyn.learned.weights import CorrectionNet, WeightFileError, load_weights, save_weights

__all__ = ["DEFAULT_FORMULATION", "FORMULATIONS", "Formulation", "formulation",
           "hybrid_expression", "hybrid_jacobian", "hybrid_step", "shipped_correction",
           "shipped_corrections", "shipped_history", "shipped_identified", "shipped_weights",
           "not_kept_reason",
           "ACTIVATIONS", "mlp_forward", "CorrectionNet", "WeightFileError", "load_weights",
           "save_weights"]
