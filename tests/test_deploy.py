"""The C deployment bundle builds with strict flags, needs no CasADi and no malloc, and its
example reproduces the Python rollout (1e-12 in double, 1e-4 in float)."""

import math
import shutil
import subprocess

import numpy as np
import pytest

from uavdyn.deploy.bundle import (
    BundleSpec,
    doublet_controls,
    export_bundle,
    model_bundle_spec,
    silence_unused_parameters,
)
from uavdyn.integrate import rk4_step, simulate
from uavdyn.model import build_model

CC = shutil.which("cc") or shutil.which("gcc")
pytestmark = pytest.mark.skipif(CC is None, reason="no C compiler")
STRICT = ["-std=c99", "-Wall", "-Wextra", "-Werror"]


def build_and_run(folder, name):
    sources = [str(folder / "main.c"), str(folder / f"{name}.c"),
               str(folder / f"{name}_generated.c")]
    exe = folder / "example_strict"
    proc = subprocess.run([CC, *STRICT, "-O2", "-o", str(exe), *sources, "-lm"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    run = subprocess.run([str(exe)], capture_output=True, text=True, check=True)
    lines = run.stdout.splitlines()
    return lines[0], np.loadtxt(lines[1:], delimiter=",")


@pytest.mark.parametrize("real, rollout_steps, tol", [
    ("double", 0, 1e-12), ("float", 0, 1e-4), ("double", 400, 1e-12),
])
@pytest.mark.parametrize("name", ["aerosonde", "f450"])
def test_bundle_matches_python(tmp_path, request, name, real, rollout_steps, tol):
    af = request.getfixturevalue(name)
    point = request.getfixturevalue("aerosonde_trim" if name == "aerosonde" else "f450_hover")
    model = build_model(af)
    step = rk4_step(model.f)
    amplitude, channel = (math.radians(2), 0) if af.kind == "fixed_wing" else (0.05, 1)
    spec = BundleSpec("uav_step", model.state_names, model.control_names, model.param_names,
                      af.p, point.x, point.u, 0.005, amplitude, doublet_channel=channel,
                      example_steps=400, real=real, rollout_steps=rollout_steps)
    folder = export_bundle(step, spec, tmp_path / "bundle")
    for f in folder.glob("*.c"):
        text = f.read_text()
        assert "malloc" not in text and "casadi.h" not in text
    header, data = build_and_run(folder, "uav_step")
    assert header == ",".join(("time",) + model.state_names + model.control_names)
    U = doublet_controls(spec)
    expected = simulate(step, point.x, U, af.p, spec.dt)
    assert data.shape == (401, 7)
    np.testing.assert_allclose(data[:-1, 5:], U, atol=1e-6 if real == "float" else 0)
    err = np.abs(data[:, 1:5] - expected).max()
    assert err <= tol, err
    assert np.ptp(expected[:, 3]) > 1e-3  # the doublet moved the pitch


@pytest.mark.parametrize("formulation, real, rollout_steps, tol", [
    ("safe", "double", 0, 1e-12), ("safe", "float", 0, 1e-4),
    ("safe", "double", 400, 1e-12), ("paper", "double", 0, 1e-12),
])
def test_hybrid_bundle_matches_python_hybrid_rollout(tmp_path, aerosonde, formulation, real,
                                                     rollout_steps, tol):
    """The shipped corrections (the safe one on its identified airframe, with its actuator
    states; the paper's on the nominal preset, with its time input) export through their
    discrete model: the example's trajectory is the Python rollout's."""
    from uavdyn.integrate import free_run, physics_step
    from uavdyn.learned import hybrid_step, shipped_identified, shipped_weights
    from uavdyn.linear import trim

    owner = shipped_identified("aerosonde") if formulation == "safe" else aerosonde
    model = hybrid_step(shipped_weights("aerosonde", formulation), owner, compile=False)
    spec = model_bundle_spec("hyb", model, trim(owner, 25.0), 0.005, example_steps=400,
                             real=real, rollout_steps=rollout_steps)
    assert spec.state_names == model.state_names and spec.has_time_input == model.takes_time
    folder = export_bundle(model, spec, tmp_path / "bundle")
    _, data = build_and_run(folder, "hyb")
    expected = free_run(model, spec.x0, doublet_controls(spec), spec.p, 0.005, compile=False)
    assert np.abs(data[:, 1:1 + model.nx] - expected).max() <= tol
    # the correction is really in the exported code: it differs from the physics alone
    physics = physics_step(owner)
    plain = simulate(physics, spec.x0[:physics.nx], doublet_controls(spec), spec.p, 0.005)
    assert np.abs(plain[:, :4] - expected[:, :4]).max() > 1e-6


def test_makefile_builds(tmp_path, aerosonde, aerosonde_trim):
    if shutil.which("make") is None:
        pytest.skip("no make")
    model = build_model(aerosonde)
    spec = BundleSpec("plane", model.state_names, model.control_names, model.param_names,
                      aerosonde.p, aerosonde_trim.x, aerosonde_trim.u, 0.01, 0.03)
    folder = export_bundle(rk4_step(model.f), spec, tmp_path / "b")
    subprocess.run(["make", "-C", str(folder)], check=True, capture_output=True)
    assert (folder / "example").exists()


def test_bad_bundle_options(tmp_path, aerosonde, aerosonde_trim):
    model = build_model(aerosonde)
    base = dict(state_names=model.state_names, control_names=model.control_names,
                param_names=model.param_names, p=aerosonde.p, x0=aerosonde_trim.x,
                u_trim=aerosonde_trim.u, dt=0.01, doublet_amplitude=0.01)
    step = rk4_step(model.f)
    with pytest.raises(ValueError, match="real must be 'double' or 'float'"):
        export_bundle(step, BundleSpec("a", real="half", **base), tmp_path)
    with pytest.raises(ValueError, match="must be a C identifier"):
        export_bundle(step, BundleSpec("my-plane", **base), tmp_path)


def test_silence_unused_parameters():
    src = "static int f(const double** arg, double* w, int mem) {\n  return 0;\n}\n"
    out = silence_unused_parameters(src)
    assert "(void)arg; (void)w; (void)mem;" in out


@pytest.mark.parametrize("rollout_steps", [0, 300])
def test_augmented_bundle_matches_python_and_lists_its_states(tmp_path, aerosonde,
                                                              rollout_steps):
    """An airframe with actuator lags and a delay exports its augmented step: the header and
    README name every state in order, the trim state is at rest, and the example's trajectory
    is the Python one to 1e-12."""
    from uavdyn.integrate import physics_step
    from uavdyn.linear import trim
    from uavdyn.model import structure_of

    af = aerosonde.replace(tau_elevator=0.05, tau_throttle=0.3).with_delays(elevator=2)
    point = trim(af, 25.0)
    names = structure_of(af).state_names()
    step = physics_step(af)
    spec = model_bundle_spec("lagged", step, point, 0.005, example_steps=300,
                             rollout_steps=rollout_steps)
    assert spec.state_names == names and len(spec.x0) == len(names) == 8
    folder = export_bundle(step, spec, tmp_path / "bundle")
    header = (folder / "lagged.h").read_text()
    assert f"x = [{', '.join(names)}]" in header and "#define LAGGED_NX 8" in header
    readme = (folder / "README.md").read_text()
    positions = [readme.index(f"`{n}`") for n in names]
    assert positions == sorted(positions)  # listed in order
    first, data = build_and_run(folder, "lagged")
    assert first == ",".join(("time",) + names + spec.control_names)
    expected = simulate(step, spec.x0, doublet_controls(spec), af.p, spec.dt)
    assert np.abs(data[:, 1:9] - expected).max() <= 1e-12
    assert np.ptp(expected[:, 4]) > 0.01  # the elevator actuator moved
    # a spec whose state does not fit the step is refused
    model = build_model(af)
    wrong = BundleSpec("w", model.state_names, model.control_names, model.param_names, af.p,
                       point.x, point.u, 0.005, 0.01)
    with pytest.raises(ValueError, match="has 8 states; the spec names 4"):
        export_bundle(step, wrong, tmp_path / "w")
