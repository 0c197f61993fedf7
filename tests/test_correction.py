"""Correction-network weight files: lossless, pickle-free round trip; clear errors for missing
keys, wrong shapes, other airframes; the CasADi rebuild equals a NumPy forward pass (VM and C)."""

import casadi as ca
import numpy as np
import pytest

from uavdyn.airframes import perturb
from uavdyn.integrate import compile_function, find_compiler
from uavdyn.learned import (
    FORMULATIONS,
    CorrectionNet,
    WeightFileError,
    load_weights,
    save_weights,
)
from uavdyn.model import NUMPY_OPS


def random_net(airframe, formulation="improved", activation="relu", hidden=16, seed=0):
    rng = np.random.default_rng(seed)
    n_in, n_out = FORMULATIONS[formulation].n_in, FORMULATIONS[formulation].n_out
    sizes = [n_in, hidden, hidden, hidden, n_out]
    return CorrectionNet(
        formulation=formulation, activation=activation, kind=airframe.kind,
        airframe_hash=airframe.param_hash(), dt=0.005,
        weights=tuple(rng.normal(size=(sizes[i + 1], sizes[i])) / np.sqrt(sizes[i])
                      for i in range(4)),
        biases=tuple(rng.normal(size=sizes[i + 1]) * 0.1 for i in range(4)),
        in_mean=rng.normal(size=n_in), in_scale=rng.uniform(0.5, 2.0, n_in),
        out_mean=rng.normal(size=n_out) * 0.01, out_scale=rng.uniform(0.01, 0.1, n_out),
        info={"note": "random test network"},
        t_range=(0.0, 60.0) if FORMULATIONS[formulation].takes_time else None)


def test_round_trip_is_lossless_and_pickle_free(tmp_path, aerosonde):
    net = random_net(aerosonde)
    path = save_weights(net, tmp_path / "w.npz")
    with np.load(path, allow_pickle=False) as data:  # would raise on any object array
        assert str(data["formulation"]) == "improved"
    back = load_weights(path, aerosonde)
    for a, b in zip(net.weights + net.biases, back.weights + back.biases):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(net.out_scale, back.out_scale)
    assert back.info == net.info and back.dt == net.dt and back.hidden == (16, 16, 16)


def _rewrite(src, dst, drop=(), **changes):
    with np.load(src, allow_pickle=False) as data:
        content = {k: data[k] for k in data.files if k not in drop}
    content.update(changes)
    with open(dst, "wb") as fh:
        np.savez(fh, **content)
    return dst


def test_malformed_files_each_give_their_message(tmp_path, aerosonde, f450):
    good = save_weights(random_net(aerosonde), tmp_path / "good.npz")

    with pytest.raises(WeightFileError, match=r"airframe_hash.*another airframe"):
        load_weights(good, perturb(aerosonde, 1.15))
    with pytest.raises(WeightFileError, match=r"key 'kind' is 'fixed_wing'.*'multirotor'"):
        load_weights(good, f450)

    bad = _rewrite(good, tmp_path / "missing.npz", drop=("W2", "out_scale"))
    with pytest.raises(WeightFileError, match=r"missing\.npz: missing key\(s\) \['out_scale', "
                                              r"'W2'\]"):
        load_weights(bad)

    bad = _rewrite(good, tmp_path / "shape.npz", W1=np.zeros((16, 12)))
    with pytest.raises(WeightFileError, match=r"shape\.npz: key 'W1' has shape \(16, 12\); "
                                              r"expected \(width, 16\)"):
        load_weights(bad)

    bad = _rewrite(good, tmp_path / "bias.npz", b0=np.zeros(5))
    with pytest.raises(WeightFileError, match=r"key 'b0' has shape \(5,\)"):
        load_weights(bad)

    bad = _rewrite(good, tmp_path / "out.npz", W3=np.zeros((4, 16)), b3=np.zeros(4))
    with pytest.raises(WeightFileError, match=r"key 'W3'.*'improved' formulation needs \(3, 16\)"):
        load_weights(bad)

    bad = _rewrite(good, tmp_path / "norm.npz", in_mean=np.zeros(5))
    with pytest.raises(WeightFileError, match=r"key 'in_mean' has shape \(5,\)"):
        load_weights(bad)

    bad = _rewrite(good, tmp_path / "form.npz", formulation=np.array("magic"))
    with pytest.raises(WeightFileError, match=r"key 'formulation' is 'magic'"):
        load_weights(bad)

    bad = _rewrite(good, tmp_path / "nan.npz", b1=np.full(16, np.nan))
    with pytest.raises(WeightFileError, match=r"key 'b1' contains non-finite"):
        load_weights(bad)

    pickled = tmp_path / "pickled.npz"
    with open(pickled, "wb") as fh:
        np.savez(fh, **{"format_version": np.array(1), "W0": np.array([{"a": 1}], dtype=object)})
    with pytest.raises(WeightFileError, match="pickled.npz"):
        load_weights(pickled)

    with pytest.raises(WeightFileError, match="not found"):
        load_weights(tmp_path / "nope.npz")


@pytest.mark.parametrize("formulation", sorted(FORMULATIONS))
@pytest.mark.parametrize("activation", ["relu", "tanh"])
def test_casadi_rebuild_equals_numpy(formulation, activation, aerosonde):
    net = random_net(aerosonde, formulation, activation)
    rng = np.random.default_rng(1)
    inputs = net.in_mean + net.in_scale * rng.uniform(-3, 3, size=(1000, net.n_in))
    expected = net.forward(inputs.T, NUMPY_OPS).T
    sym = ca.SX.sym("inp", net.n_in)
    vm = ca.Function("correction", [sym], [net.casadi(sym)]).map(1000)
    got = np.array(vm(inputs.T)).T
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10 * np.abs(expected).max())
    if find_compiler() is not None:
        compiled = compile_function(vm)
        np.testing.assert_allclose(np.array(compiled(inputs.T)).T, expected, rtol=0,
                                   atol=1e-10 * np.abs(expected).max())
