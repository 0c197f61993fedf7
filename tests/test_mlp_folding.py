"""The compiled step's network (normalisation folded into the weights, balanced sums) is the
trained network: NumPy forward pass vs the folded one vs the CasADi expression."""

import casadi as ca
import numpy as np
import pytest

from uavdyn.learned.mlp import folded_forward, folded_layers, mlp_forward
from uavdyn.model.ops import CASADI_OPS, NUMPY_OPS


def _random_net(rng, sizes, with_skip):
    weights = [rng.normal(size=(sizes[i + 1], sizes[i])) for i in range(len(sizes) - 1)]
    weights[0][0, 1] = 0.0  # a zero weight is left out of the folded sums
    biases = [rng.normal(size=sizes[i + 1]) for i in range(len(sizes) - 1)]
    in_mean, in_scale = rng.normal(size=sizes[0]), rng.uniform(0.1, 5.0, sizes[0])
    out_mean, out_scale = rng.normal(size=sizes[-1]), rng.uniform(0.01, 3.0, sizes[-1])
    skip = rng.normal(size=(sizes[-1], sizes[0])) if with_skip else None
    return weights, biases, in_mean, in_scale, out_mean, out_scale, skip


@pytest.mark.parametrize("sizes,with_skip", [((7, 5, 4, 3), True), ((4, 6, 3), False),
                                             ((3, 3), True)])
def test_folded_network_equals_the_trained_one(sizes, with_skip):
    rng = np.random.default_rng(3)
    w, b, im, isc, om, osc, skip = _random_net(rng, sizes, with_skip)
    inp = rng.normal(size=(sizes[0], 50)) * 3.0
    reference = mlp_forward(w, b, im, isc, om, osc, inp, NUMPY_OPS, "relu", skip=skip)
    fw, fb, fskip = folded_layers(w, b, im, isc, om, osc, skip)
    folded = folded_forward(fw, fb, inp, NUMPY_OPS, fskip)
    scale = np.max(np.abs(reference))
    assert np.max(np.abs(folded - reference)) < 1e-12 * scale
    x = ca.SX.sym("x", sizes[0])
    f = ca.Function("f", [x], [folded_forward(fw, fb, x, CASADI_OPS, fskip)])
    symbolic = np.column_stack([np.asarray(f(inp[:, k])).ravel() for k in range(5)])
    assert np.max(np.abs(symbolic - reference[:, :5])) < 1e-12 * scale
