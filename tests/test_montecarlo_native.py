"""Monte-Carlo chunks as one C loop, four runs at a time (``uavdyn.montecarlo.native``, issue 32):

* every operation written in lanes gives, lane by lane, bit for bit what CasADi's own generated
  scalar code gives (special values included), a sine and cosine of one operand in one call;
* a chunk equals the compiled ``map`` of the ``mapaccum`` run bit for bit on a non-preset fixed
  wing with gusts and dispersed initial states, a non-preset quadrotor in closed loop and the
  shipped hybrid correction, with a run count that leaves lanes empty, on 1 and 2 threads;
* runs that diverge at different times keep their own statistics and divergence times;
* a body the lanes cannot write runs through CasADi's map, with a warning;
* one library serves every chunk size up to its capacity and every thread count;
* with vector math (glibc's libmvec, where the machine has it) every operation and a whole
  gusty chunk agree with the scalar code to round-off, and where it is missing the study says
  why.
"""

from __future__ import annotations

import ctypes
import dataclasses
import subprocess
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from uavdyn.airframes import load_airframe
from uavdyn.integrate import compile_function, find_compiler
from uavdyn.integrate.compiler import CodegenWarning
from uavdyn.integrate.lanes import VECTOR_FLAGS, LanesError, lanes_c, vector_math_unavailable
from uavdyn.learned import shipped_correction
from uavdyn.linear import trim
from uavdyn.model import structure_of
from uavdyn.montecarlo import MonteCarloError, build_spec, load_dispersions
from uavdyn.montecarlo import chunks as chunk_module
from uavdyn.montecarlo import spec as spec_module
from uavdyn.montecarlo.batch import batch_function, run_function, run_pieces
from uavdyn.montecarlo.native import FLAGS, LANES, NativeBatch, native_batch

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
needs_cc = pytest.mark.skipif(find_compiler() is None, reason="no C compiler")
needs_vector_math = pytest.mark.skipif(vector_math_unavailable() is not None,
                                       reason=f"no vector math: {vector_math_unavailable()}")


def _every_operation() -> ca.Function:
    x, y = ca.SX.sym("x", 3), ca.SX.sym("y", 3)
    a, b, c = ca.vertsplit(x)
    d, e, f = ca.vertsplit(y)
    out = [a + d, a - d, a * d, a / d, -a, a**2, 2 * a, 1 / b, ca.fabs(a), ca.exp(a), ca.log(b),
           ca.sqrt(b), ca.sin(a), ca.cos(a), ca.tan(a), ca.asin(c), ca.acos(c), ca.atan(a),
           ca.sinh(a), ca.cosh(a), ca.tanh(a), ca.asinh(a), ca.acosh(1 + b), ca.atanh(c),
           ca.floor(a), ca.ceil(a), ca.erf(a), ca.expm1(a), ca.log1p(b), a < d, a <= d, a == d,
           a != d, ca.logic_and(a, d), ca.logic_or(a, d), ca.logic_not(a),
           ca.if_else(a > d, e, f), b**d, a**3, ca.fmin(a, d), ca.fmax(a, d), ca.atan2(a, d),
           ca.fmod(a, d), ca.remainder(a, d), ca.hypot(a, d), ca.copysign(a, d), ca.sign(a),
           a + np.inf, a * np.nan, a - np.inf, ca.cos(a * d) * ca.sin(a * d)]
    return ca.Function("every_op", [x, y], [ca.vertcat(*out)])


def _lanes_library(func: ca.Function, folder: Path, vector_math: bool = False) -> ctypes.CDLL:
    source = folder / "lanes.c"
    source.write_text("#include <math.h>\ntypedef double casadi_real;\n"
                      + lanes_c(func, "f_lanes", LANES, vector_math)
                      + "CASADI_SYMBOL_EXPORT void call(const double* const* arg, "
                        "double* const* res) { f_lanes(arg, res); }\n")
    library = folder / "lanes.so"
    flags = (*FLAGS, *VECTOR_FLAGS) if vector_math else FLAGS
    subprocess.run([find_compiler(), *flags, str(source), "-o", str(library), "-lm"],
                   check=True, capture_output=True)
    return ctypes.CDLL(str(library))


@needs_cc
@pytest.mark.parametrize("vector_math", [False, pytest.param(True, marks=needs_vector_math)])
def test_every_operation_in_lanes_equals_casadis_scalar_code(tmp_path, vector_math):
    """Bit for bit; with vector math to a few units in the last place (libmvec's accuracy),
    special values (signed zeros, infinities, NaN) alike."""
    func = _every_operation()
    scalar = compile_function(func, FLAGS, directory=tmp_path / "cache")
    library = _lanes_library(func, tmp_path, vector_math)
    rng = np.random.default_rng(5)
    values = rng.uniform(-3, 3, (2, 3, 4 * LANES))
    specials = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 1.0, -1.0, 0.5])
    values[0, :, :8], values[1, :, :8] = specials, specials[::-1]
    n_out = func.size1_out(0)
    for start in range(0, values.shape[2], LANES):
        block = values[:, :, start:start + LANES]
        args = [np.ascontiguousarray(block[i]) for i in range(2)]  # element j, lane b at j*4+b
        out = np.empty((n_out, LANES))
        arg = (ctypes.c_void_p * 2)(*(a.ctypes.data for a in args))
        res = (ctypes.c_void_p * 1)(out.ctypes.data)
        with np.errstate(all="ignore"):
            library.call(arg, res)
        for lane in range(LANES):
            expected = np.asarray(scalar(block[0, :, lane], block[1, :, lane])).ravel()
            if vector_math:
                np.testing.assert_allclose(out[:, lane], expected, rtol=1e-14, atol=1e-300)
            else:
                np.testing.assert_array_equal(out[:, lane], expected)


def test_a_sine_and_cosine_of_one_operand_share_one_sincos_call():
    x = ca.SX.sym("x", 2)
    shared = ca.Function("f", [x], [ca.vertcat(ca.sin(x[0]), ca.cos(x[0]) * ca.sin(x[1]),
                                               ca.cos(2 * x[1]), ca.sin(x[0] + x[1]))])
    text = lanes_c(shared, "f_lanes", LANES)
    assert text.count("UAVDYN_SINCOS(w[") == 1  # only sin(x0) and cos(x0) share an operand
    assert text.count("sin(w[") == 2 and text.count("cos(w[") == 1
    alone = ca.Function("g", [x], [ca.sin(x[0]) + ca.cos(x[1])])
    assert "UAVDYN_SINCOS" not in lanes_c(alone, "g_lanes", LANES)


@needs_vector_math
def test_a_gusty_chunk_with_vector_math_agrees_with_the_scalar_chunk_to_round_off(tmp_path):
    """The own fixed wing with gusts for 10 s: every statistic within 1e-12 (relative) of the
    bit-for-bit route's, the same runs trimmed and diverged, the envelope samples equal as the
    stored float32; a different study key (resume never mixes the two)."""
    airframe = load_airframe(EXAMPLES / "trainer.toml")
    dispersions = _dispersions(tmp_path, TRAINER_DISPERSIONS, airframe)
    chunks = {}
    for vector_math in (False, True):
        spec = build_spec(airframe, dispersions, runs=6, duration=10.0, dt=0.01,
                          mission="3211", chunk_size=6, history_dt=0.1,
                          vector_math=vector_math)
        chunks[vector_math] = (spec.key, chunk_module.evaluate_chunk(spec, 0))
    (key, scalar), (vector_key, vector) = chunks[False], chunks[True]
    assert key != vector_key
    np.testing.assert_array_equal(np.isnan(vector.table), np.isnan(scalar.table))
    np.testing.assert_allclose(vector.table, scalar.table, rtol=1e-12, atol=0)
    np.testing.assert_allclose(vector.history, scalar.history, rtol=1e-6, atol=0)  # float32


def test_vector_math_where_the_machine_lacks_it_is_refused_with_the_reason(monkeypatch,
                                                                          aerosonde):
    monkeypatch.setattr(spec_module, "vector_math_unavailable",
                        lambda: "the CPU has no AVX2")
    dispersions = load_dispersions("aerosonde_pm15", aerosonde)
    with pytest.raises(MonteCarloError, match="vector math is not available here: the CPU has "
                                              "no AVX2; leave out --vector-math"):
        build_spec(aerosonde, dispersions, runs=2, duration=1.0, vector_math=True)
    # a Dask worker unlike the client: the chunk refuses instead of running AVX2 code
    spec = build_spec(aerosonde, dispersions, runs=2, duration=1.0, chunk_size=2)
    monkeypatch.setattr(chunk_module, "vector_math_unavailable", lambda: "the CPU has no AVX2")
    chunk_module._COMPILED.clear()
    with pytest.raises(MonteCarloError, match="not available on this worker"):
        chunk_module.evaluate_chunk(dataclasses.replace(spec, vector_math=True), 0)
    x = ca.SX.sym("x")
    with pytest.raises(LanesError, match="4 lanes"):
        lanes_c(ca.Function("e", [x], [ca.exp(x)]), "e", 2, vector_math=True)


def test_lanes_refuse_an_mx_function_and_an_operation_without_c():
    x = ca.MX.sym("x")
    with pytest.raises(LanesError, match="not an SX Function"):
        lanes_c(ca.Function("m", [x], [2 * x]), "m", 4)
    s = ca.SX.sym("s")
    with pytest.raises(LanesError, match="ERFINV"):
        lanes_c(ca.Function("e", [s], [ca.erfinv(s)]), "e", 4)


# ----------------------------------------------------------------------------- whole chunks

TRAINER_DISPERSIONS = """
seed = 11
[params.C_m_alpha]
dist = "uniform"
low = -0.2
high = 0.2
[params.mass]
dist = "normal"
sd = 0.03
[initial]
theta = { dist = "normal", sd = 0.03 }
q = { dist = "uniform", low = -0.05, high = 0.05 }
[gust]
intensity = { dist = "uniform", low = 0.0, high = 2.0 }
"""

X500_DISPERSIONS = """
seed = 4
[params.mass]
dist = "uniform"
low = -0.1
high = 0.1
[params.Jy]
dist = "uniform"
low = -0.2
high = 0.2
[initial]
theta = { dist = "normal", sd = 0.05 }
"""


def _dispersions(folder: Path, text: str, airframe):
    path = folder / "dispersions.toml"
    path.write_text(text)
    return load_dispersions(path, airframe)


def _both_routes(spec, threads: int, monkeypatch):
    """(chunk through the native loop, chunk through the compiled map of the mapaccum run)."""
    chunk_module._COMPILED.clear()
    assert isinstance(chunk_module.compiled_batch(spec, spec.runs, threads), NativeBatch)
    native = chunk_module.evaluate_chunk(spec, 0, threads)
    chunk_module._COMPILED.clear()
    with monkeypatch.context() as m:
        m.setattr(chunk_module, "native_batch", lambda *args, **kwargs: None)
        assert isinstance(chunk_module.compiled_batch(spec, spec.runs, threads), ca.Function)
        reference = chunk_module.evaluate_chunk(spec, 0, threads)
    chunk_module._COMPILED.clear()
    return native, reference


def _assert_same(native, reference):
    np.testing.assert_array_equal(native.table, reference.table)
    np.testing.assert_array_equal(native.history, reference.history)


@needs_cc
def test_a_gusty_chunk_of_the_own_fixed_wing_equals_the_mapped_run(tmp_path, monkeypatch):
    airframe = load_airframe(EXAMPLES / "trainer.toml")
    dispersions = _dispersions(tmp_path, TRAINER_DISPERSIONS, airframe)
    spec = build_spec(airframe, dispersions, runs=7, duration=3.0, dt=0.01, mission="3211",
                      chunk_size=7, history_dt=0.1)
    native, reference = _both_routes(spec, 1, monkeypatch)
    _assert_same(native, reference)
    assert np.all(np.isfinite(native.history)) and not np.any(native.table[:, 2])
    # the same library on two threads, and for a chunk of fewer runs than it was built for
    two = chunk_module.evaluate_chunk(spec, 0, 2)
    _assert_same(two, reference)
    fewer = dataclasses.replace(spec, runs=5)
    part = chunk_module.evaluate_chunk(fewer, 0, 2)
    assert part.table.shape[0] == 5
    np.testing.assert_array_equal(part.table, reference.table[:5])
    np.testing.assert_array_equal(part.history, reference.history[:5])


@needs_cc
def test_a_closed_loop_chunk_of_the_own_quadrotor_equals_the_mapped_run(tmp_path, monkeypatch):
    airframe = load_airframe(EXAMPLES / "x500.toml")
    dispersions = _dispersions(tmp_path, X500_DISPERSIONS, airframe)
    spec = build_spec(airframe, dispersions, runs=6, duration=2.0, dt=0.01, chunk_size=6,
                      closed_loop=True, history_dt=0.05)
    _assert_same(*_both_routes(spec, 1, monkeypatch))


@needs_cc
def test_a_hybrid_chunk_equals_the_mapped_run(tmp_path, monkeypatch):
    weights, airframe = shipped_correction("aerosonde")
    dispersions = _dispersions(tmp_path, X500_DISPERSIONS.replace("Jy", "C_m_q"), airframe)
    spec = build_spec(airframe, dispersions, runs=5, duration=1.5, dt=0.01, chunk_size=5,
                      weights=weights)
    _assert_same(*_both_routes(spec, 1, monkeypatch))


def _doubling(airframe):
    x, u = ca.SX.sym("x", 4), ca.SX.sym("u", 2)
    p, dt = ca.SX.sym("p", len(airframe.p)), ca.SX.sym("dt")
    return x, u, p, dt


@needs_cc
def test_runs_diverging_at_different_times_keep_their_own_statistics(aerosonde):
    """Pitch doubled every step from 0.01 * 2**-k leaves |theta| <= pi at step 9 + k: the runs
    of one group of four diverge at different steps (and one never within 30 steps); each has
    its own divergence time and statistics, equal to the mapped run's."""
    x, u, p, dt = _doubling(aerosonde)
    doubling = ca.Function("doubling", [x, u, p, dt], [ca.vertcat(x[:3], 2 * x[3])])
    structure, n_steps, stride = structure_of(aerosonde), 30, 5
    point = trim(aerosonde)
    run = run_function(doubling, aerosonde, structure, n_steps, stride, False)
    pieces = run_pieces(doubling, aerosonde, structure, False)
    runs = 6
    mapped = batch_function(run, runs, compile=False)
    native = native_batch(pieces, batch_function(run, runs + 3, compile=False), n_steps,
                          stride, False, False)
    assert isinstance(native, NativeBatch) and native.capacity == runs + 3  # fewer runs fit
    theta0 = 0.01 * 2.0 ** -np.array([0, 3, 1, 25, 2, 0])
    x0 = np.vstack([np.tile(point.x[:3, None], (1, runs)), theta0])
    args = (x0, np.tile(point.u[:, None], (1, runs)), np.tile(aerosonde.p[:, None], (1, runs)),
            np.zeros((2, n_steps)), 0.01, [np.inf, np.inf, -np.inf, np.inf])
    stats, hist = native(*args)
    ref_stats, ref_hist = (np.asarray(a) for a in mapped(*args))
    np.testing.assert_array_equal(stats, ref_stats)
    t_div = stats[-1]
    np.testing.assert_allclose(t_div, [0.09, 0.12, 0.10, -1, 0.11, 0.09], atol=1e-12)
    times = np.arange(n_steps // stride + 1) * stride * 0.01
    hist, ref_hist = hist.reshape(5, runs, -1), ref_hist.reshape(5, runs, -1)
    for r in range(runs):
        kept = times < t_div[r] - 1e-12 if t_div[r] >= 0 else times >= 0
        np.testing.assert_array_equal(hist[:, r, kept], ref_hist[:, r, kept])


def test_a_body_without_lane_form_runs_through_casadis_map_with_a_warning(aerosonde):
    x, u, p, dt = _doubling(aerosonde)
    odd = ca.Function("odd", [x, u, p, dt], [ca.vertcat(x[:3], x[3] + 1e-9 * ca.erfinv(x[3]))])
    structure = structure_of(aerosonde)
    run = run_function(odd, aerosonde, structure, 4, 2, False)
    mapped = batch_function(run, 2, compile=False)
    with pytest.warns(CodegenWarning, match="ERFINV"):
        batch = native_batch(run_pieces(odd, aerosonde, structure, False), mapped, 4, 2, False,
                             False)
    assert batch is None  # the caller flies CasADi's map
