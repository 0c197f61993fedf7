"""The compile cache loads only libraries it built and verified: a poisoned, truncated or foreign
library under a cache name is never dlopened (rebuilt, or refused when it cannot be rebuilt);
unsafe cache folders are refused; failed or garbage builds never land under the final name;
threads and processes compiling the same Function concurrently all succeed. Plus: weight files
are written atomically."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import numpy as np
import pytest
from fuzz_cache import (
    FUNCTION,
    cache_env,
    failing_compiler,
    garbage_compiler,
    genuine_library,
    poison_library,
    real_compiler,
    small_function,
    write_script,
)

from uavdyn.integrate import codegen, rk4_step, rollout
from uavdyn.integrate.codegen import CacheError, CompileError
from uavdyn.model import build_model

needs_cc = pytest.mark.skipif(real_compiler() is None, reason="no C compiler")
X = [0.3, -1.2, 2.0]


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    """A private, empty cache folder (not yet created) and the real compiler."""
    folder = tmp_path / "cache"
    monkeypatch.setenv(codegen.CACHE_ENV, str(folder))
    monkeypatch.delenv(codegen.COMPILER_ENV, raising=False)
    return folder


def expected(func=None) -> np.ndarray:
    return np.array((func or small_function())(X)).ravel()


def sidecar_of(lib: Path) -> Path:
    return lib.with_name(lib.name + codegen.SIDECAR_SUFFIX)


def leftovers(folder: Path) -> list[str]:
    """Files other than verified libraries, their sidecars and lock files."""
    return sorted(p.name for p in folder.iterdir()
                  if not (p.name.endswith((".so", codegen.SIDECAR_SUFFIX, ".lock"))))


def assert_verified(lib: Path) -> None:
    record = json.loads(sidecar_of(lib).read_text())
    import hashlib
    assert record["sha256"] == hashlib.sha256(lib.read_bytes()).hexdigest()
    assert record["library"] == lib.name and record["function"] == lib.name.rsplit("_", 1)[0]


# -- normal operation --------------------------------------------------------------------------

@needs_cc
def test_build_writes_private_folder_library_and_sidecar(cache):
    f = small_function()
    g = codegen.compile_function(f)
    assert g.class_name() == "External"
    np.testing.assert_allclose(np.array(g(X)).ravel(), expected(), rtol=0, atol=1e-14)
    assert oct(cache.stat().st_mode & 0o777) == oct(0o700)
    lib = codegen.library_path(f)
    assert sorted(p.name for p in cache.iterdir() if not p.name.startswith(".")) == \
        [lib.name, sidecar_of(lib).name]
    assert_verified(lib)
    assert leftovers(cache) == []
    mtime = lib.stat().st_mtime_ns
    codegen.compile_function(f)  # verified and reused, not rebuilt
    assert lib.stat().st_mtime_ns == mtime


# -- libraries that no build of this source produced -------------------------------------------

@needs_cc
@pytest.mark.parametrize("sidecar", ["none", "stale", "forged"])
def test_poisoned_library_is_rebuilt_never_loaded(cache, tmp_path, sidecar):
    f = small_function()
    lib = codegen.library_path(f)
    marker = tmp_path / "marker"
    if sidecar == "stale":  # a genuine build first, then the library swapped under its sidecar
        codegen.compile_function(f)
    cache.mkdir(mode=0o700, exist_ok=True)
    poison_library(lib, marker)
    lib.chmod(0o700)
    poison = lib.read_bytes()
    if sidecar == "forged":  # names this library and its hash, but not a build of this source
        import hashlib
        sidecar_of(lib).write_text(json.dumps(
            {"format": 1, "library": lib.name, "sha256": hashlib.sha256(poison).hexdigest(),
             "size": len(poison), "key": "0" * 64, "function": FUNCTION}))
    g = codegen.compile_function(f)
    assert not marker.exists(), "the poisoned library was loaded"
    np.testing.assert_allclose(np.array(g(X)).ravel(), expected(), rtol=0, atol=1e-14)
    assert lib.read_bytes() != poison
    assert_verified(lib)
    assert leftovers(cache) == []


@needs_cc
def test_poisoned_library_refused_when_it_cannot_be_rebuilt(cache, tmp_path, monkeypatch):
    cc = failing_compiler(tmp_path)
    monkeypatch.setenv(codegen.COMPILER_ENV, str(cc))
    lib = codegen.library_path(small_function())
    cache.mkdir(mode=0o700)
    marker = tmp_path / "marker"
    poison_library(lib, marker)
    with pytest.raises(CacheError) as info:
        codegen.compile_function(small_function())
    message = str(info.value)
    assert "\n" not in message and str(lib) in message and "no sidecar" in message
    assert str(cc) in message and FUNCTION in message
    assert info.value.path == lib
    assert not marker.exists(), "the poisoned library was loaded"


TRUNCATED_SCRIPT = textwrap.dedent("""
    import json, os, sys
    from fuzz_cache import small_function
    from uavdyn.integrate import codegen
    f = small_function()
    first = codegen.compile_function(f)          # loaded and mapped in this process
    lib = codegen.library_path(f)
    data = lib.read_bytes()                      # half a library, as an interrupted copy or
    half = lib.with_name("half.tmp")             # a non-atomic writer leaves it; sidecar kept
    half.write_bytes(data[:len(data) // 2])      # (a new file: truncating the mapped one in
    os.replace(half, lib)                        # place would crash any process using it)
    mode = sys.argv[1]
    if mode == "fresh":                          # a new process meets the truncated library
        os.execv(sys.executable, [sys.executable, "-c",
                 "from fuzz_cache import small_function; from uavdyn.integrate import codegen;"
                 "print(float(codegen.compile_function(small_function())([0.3, -1.2, 2.0])[0]))"])
    if mode == "failing":                        # the same, where no rebuild is possible
        failing = sys.argv[2]
        target = codegen.library_path(f, compiler=failing)
        record = json.loads(open(str(lib) + ".sha256").read())
        record.update(library=target.name, key=codegen.cache_key(f, compiler=failing))
        open(str(target) + ".sha256", "w").write(json.dumps(record))
        open(target, "wb").write(open(lib, "rb").read())
        os.chmod(target, 0o700)
        os.environ["UAVDYN_CC"] = failing
        try:
            codegen.compile_function(f)
        except codegen.CacheError as exc:
            print("refused:", exc)
        sys.exit(0)
    second = codegen.compile_function(f)         # same process: must not reuse the old mapping
    print(float(second([0.3, -1.2, 2.0])[0]))
""")


@needs_cc
@pytest.mark.parametrize("mode", ["same-process", "fresh", "failing"])
def test_truncated_library_is_refused_without_crash(cache, tmp_path, mode):
    """Run in a subprocess: a SIGBUS from mapping half a library fails the test, not pytest."""
    script = tmp_path / "truncate.py"
    script.write_text(TRUNCATED_SCRIPT)
    cc = failing_compiler(tmp_path)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(Path(__file__).parent), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, str(script), mode, str(cc)], capture_output=True,
                          text=True, env=env, timeout=300)
    assert proc.returncode == 0, f"crashed ({proc.returncode}): {proc.stderr[-2000:]}"
    if mode == "failing":
        assert proc.stdout.startswith("refused:") and "\n" not in proc.stdout.strip()
    else:
        assert float(proc.stdout.strip().splitlines()[-1]) == pytest.approx(expected()[0],
                                                                             abs=1e-14)
        lib = codegen.library_path(small_function())
        assert_verified(lib)


@needs_cc
@pytest.mark.parametrize("with_sidecar", [False, True])
def test_short_rollout_under_long_rollout_name_is_not_used(cache, aerosonde, aerosonde_trim,
                                                          with_sidecar):
    step = rk4_step(build_model(aerosonde).f)
    r10, r50 = rollout(step, 10), rollout(step, 50)
    assert r10.name() == r50.name()
    codegen.compile_function(r10)
    lib10, lib50 = codegen.library_path(r10), codegen.library_path(r50)
    shutil.copyfile(lib10, lib50)
    lib50.chmod(0o700)
    if with_sidecar:
        shutil.copyfile(sidecar_of(lib10), sidecar_of(lib50))
    g = codegen.compile_function(r50)
    U = np.tile(aerosonde_trim.u + [0.02, 0.0], (50, 1)).T
    got = np.array(g(aerosonde_trim.x, U, aerosonde.p, 0.01))
    assert got.shape == (4, 50)
    want = np.array(r50(aerosonde_trim.x, U, aerosonde.p, 0.01))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert lib50.read_bytes() != lib10.read_bytes()
    assert_verified(lib50)


@needs_cc
def test_tampered_sidecar_or_symlinked_library_is_rebuilt(cache, tmp_path):
    f = small_function()
    codegen.compile_function(f)
    lib = codegen.library_path(f)
    record = json.loads(sidecar_of(lib).read_text())
    record["sha256"] = "0" * 64
    sidecar_of(lib).write_text(json.dumps(record))
    codegen.compile_function(f)
    assert_verified(lib)
    elsewhere = genuine_library(tmp_path / "other")
    lib.unlink()
    lib.symlink_to(elsewhere)
    g = codegen.compile_function(f)
    assert not lib.is_symlink()
    assert_verified(lib)
    np.testing.assert_allclose(np.array(g(X)).ravel(), expected(), rtol=0, atol=1e-14)


# -- concurrency -------------------------------------------------------------------------------

@needs_cc
def test_threads_compiling_the_same_function_all_succeed(cache, aerosonde, aerosonde_trim):
    f = build_model(aerosonde).f
    barrier = threading.Barrier(8)
    results: list = [None] * 8
    errors: list = []

    def work(i: int) -> None:
        try:
            barrier.wait()
            g = codegen.compile_function(f)
            results[i] = np.array(g(aerosonde_trim.x + [1.0, 0.5, 0.1, 0.0], aerosonde_trim.u,
                                    aerosonde.p))
        except BaseException as exc:  # reported below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    want = np.array(f(aerosonde_trim.x + [1.0, 0.5, 0.1, 0.0], aerosonde_trim.u, aerosonde.p))
    for r in results:
        np.testing.assert_allclose(r, want, rtol=0, atol=1e-12)
    assert len(list(cache.glob("*.so"))) == 1 and leftovers(cache) == []
    assert_verified(next(cache.glob("*.so")))


PROCESS_SCRIPT = textwrap.dedent("""
    import json, sys, time
    from uavdyn.airframes import load_airframe
    from uavdyn.integrate import codegen
    from uavdyn.model import build_model
    af = load_airframe("aerosonde")
    f = build_model(af).f
    while time.time() < float(sys.argv[1]):
        time.sleep(0.001)
    g = codegen.compile_function(f)
    x = [25.0, 1.0, 0.1, 0.05]
    print(json.dumps([float(v) for v in g(x, [-0.05, 0.5], af.p).full().ravel()]))
""")


@pytest.mark.slow
@needs_cc
def test_two_processes_compiling_the_same_function_both_succeed(cache, tmp_path):
    import time
    script = tmp_path / "proc.py"
    script.write_text(PROCESS_SCRIPT)
    start = time.time() + 4.0  # both start compiling at the same moment
    procs = [subprocess.Popen([sys.executable, str(script), str(start)], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    outs = [p.communicate(timeout=300) for p in procs]
    for p, (_, err) in zip(procs, outs):
        assert p.returncode == 0, err[-2000:]
    a, b = (json.loads(out) for out, _ in outs)
    assert a == b
    assert len(list(cache.glob("*.so"))) == 1 and leftovers(cache) == []


# -- unsafe folders and bad compilers ----------------------------------------------------------

@needs_cc
@pytest.mark.parametrize("mode", [0o777, 0o1777])
def test_world_writable_cache_folder_is_refused(cache, mode):
    cache.mkdir()
    cache.chmod(mode)
    with pytest.raises(CacheError) as info:
        codegen.compile_function(small_function())
    message = str(info.value)
    assert "\n" not in message and str(cache) in message and "world-writable" in message
    assert list(cache.iterdir()) == []


@needs_cc
@pytest.mark.skipif(not hasattr(os, "getuid") or os.getuid() != 0,
                    reason="chown to another user needs root")
def test_foreign_owned_cache_folder_is_refused(cache):
    cache.mkdir(mode=0o700)
    os.chown(cache, 54321, 54321)
    with pytest.raises(CacheError, match=r"owned by uid 54321") as info:
        codegen.compile_function(small_function())
    assert str(cache) in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("script", ["garbage", "empty", "half-elf"])
def test_compiler_exiting_0_with_garbage_never_lands_in_cache(cache, tmp_path, monkeypatch,
                                                              script):
    if script == "garbage":
        cc = garbage_compiler(tmp_path)
    elif script == "empty":
        cc = write_script(tmp_path, "cc-empty", "exit 0")
    else:
        cc = write_script(tmp_path, "cc-half", "printf '\\177ELF\\002\\001\\001\\000' > "
                                               "\"$out\"\nhead -c 5000 /dev/zero >> \"$out\"")
    monkeypatch.setenv(codegen.COMPILER_ENV, str(cc))
    with pytest.raises(CompileError) as info:
        codegen.compile_function(small_function())
    message = str(info.value)
    assert "\n" not in message and str(cc) in message and f"'{FUNCTION}'" in message
    assert "exited 0" in message
    assert sorted(p.name for p in cache.iterdir() if not p.name.endswith(".lock")) == []


def test_failing_compiler_gives_one_line_with_full_output_kept(cache, tmp_path, monkeypatch):
    cc = failing_compiler(tmp_path)
    monkeypatch.setenv(codegen.COMPILER_ENV, str(cc))
    with pytest.raises(CompileError) as info:
        codegen.compile_function(small_function())
    exc = info.value
    assert not isinstance(exc, CacheError)
    assert "\n" not in str(exc) and str(cc) in str(exc) and f"'{FUNCTION}'" in str(exc)
    assert "second line of compiler output" not in str(exc)
    assert "second line of compiler output" in exc.stderr and exc.returncode == 1
    assert exc.compiler == str(cc) and exc.function == FUNCTION and exc.command[0] == str(cc)
    assert sorted(p.name for p in cache.iterdir() if not p.name.endswith(".lock")) == []


@needs_cc
def test_no_dlopen_of_a_library_the_cache_did_not_write(cache, tmp_path):
    """Whatever sits under the cache name is hashed before ``dlopen``: an otherwise valid library
    of the same Function without our sidecar is replaced, not loaded."""
    f = small_function()
    with cache_env(tmp_path / "elsewhere"):
        codegen.compile_function(f)
    donor = codegen.library_path(f, directory=tmp_path / "elsewhere")
    lib = codegen.library_path(f)
    cache.mkdir(mode=0o700)
    shutil.copyfile(donor, lib)
    lib.chmod(0o700)
    before = lib.stat().st_ino
    codegen.compile_function(f)
    assert lib.stat().st_ino != before  # rebuilt and renamed into place
    assert_verified(lib)


# -- weight files are written atomically -------------------------------------------------------

def test_save_weights_is_atomic(tmp_path, aerosonde, monkeypatch):
    from test_correction import random_net

    from uavdyn.learned import load_weights, save_weights
    path = tmp_path / "w.npz"
    save_weights(random_net(aerosonde, seed=0), path)
    old = path.read_bytes()

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez", interrupted)
    with pytest.raises(KeyboardInterrupt):
        save_weights(random_net(aerosonde, seed=1), path)
    assert path.read_bytes() == old  # the old file intact, no temporary left behind
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.npz"]
    monkeypatch.undo()
    save_weights(random_net(aerosonde, seed=1), path)
    assert path.read_bytes() != old and load_weights(path).dt == 0.005
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.npz"]


def test_a_graph_calling_a_compiled_function_is_refused_not_crashed(tmp_path):
    """Generated C that calls an External would fail to resolve its symbol when called (a
    process-killing error): compile_function refuses it with one line naming the callee."""
    from uavdyn.airframes import load_airframe
    from uavdyn.integrate import CompileError, compile_function, physics_step, rollout

    airframe = load_airframe("aerosonde")
    step = compile_function(physics_step(airframe).function, directory=tmp_path)
    if not step.is_a("External"):
        pytest.skip("no C compiler")
    with pytest.raises(CompileError, match="calls the already compiled Function"):
        compile_function(rollout(step, 5), directory=tmp_path)
    assert compile_function(rollout(physics_step(airframe), 5), directory=tmp_path).is_a(
        "External")


@pytest.mark.slow
def test_a_compiler_that_never_exits_is_killed_and_the_vm_used(tmp_path, monkeypatch):
    """A compiler that hangs (and starts a child that hangs too) is killed, with its child,
    after $UAVDYN_CC_TIMEOUT seconds; the Function runs in the VM with one warning naming the
    compiler and the Function, and the hung compiler is not called again in this process."""
    import time
    import warnings

    import casadi as ca

    pid_file = tmp_path / "pids"
    hung = tmp_path / "hung-cc"
    hung.write_text(f"#!/bin/sh\necho $$ >> {pid_file}\nsleep 1000 &\necho $! >> {pid_file}\n"
                    "wait\n")
    hung.chmod(0o755)
    monkeypatch.setenv("UAVDYN_CC", str(hung))
    monkeypatch.setenv("UAVDYN_CC_TIMEOUT", "1.5")
    monkeypatch.setattr(codegen, "_timed_out", {})
    x = ca.SX.sym("x")
    f = ca.Function("hang_probe", [x], [ca.sin(x)])
    start = time.perf_counter()
    with pytest.warns(codegen.CodegenWarning) as caught:
        g = codegen.compile_function(f, directory=tmp_path / "cache")
    elapsed = time.perf_counter() - start
    assert g is f and float(g(0.5)) == pytest.approx(np.sin(0.5))
    assert 1.5 <= elapsed < 15.0, elapsed
    message = str(caught[0].message)
    assert str(hung) in message and "'hang_probe'" in message and "within 1.5 s" in message
    for pid in map(int, pid_file.read_text().split()):  # the compiler and its child are gone
        for _ in range(50):
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.05)
        else:
            pytest.fail(f"process {pid} of the hung compiler is still running")
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert codegen.compile_function(f, directory=tmp_path / "cache") is f
    assert time.perf_counter() - start < 1.0  # not called again
    assert not list((tmp_path / "cache").glob("*.so"))  # nothing half-built under the name


@pytest.mark.parametrize("value", ["0", "-1", "soon", "inf"])
def test_a_bad_compiler_timeout_is_refused_naming_the_variable(value, monkeypatch):
    from uavdyn.integrate.compiler import compile_timeout

    monkeypatch.setenv("UAVDYN_CC_TIMEOUT", value)
    with pytest.raises(ValueError, match="UAVDYN_CC_TIMEOUT must be a positive number"):
        compile_timeout()


def test_the_default_compiler_timeout_grows_with_the_source(monkeypatch):
    """Half a minute for a step or rollout (kilobytes of C), more for the identification's
    tens of megabytes; $UAVDYN_CC_TIMEOUT overrides it."""
    from uavdyn.integrate.compiler import compile_timeout

    monkeypatch.delenv("UAVDYN_CC_TIMEOUT", raising=False)
    assert compile_timeout(20_000) == pytest.approx(30.4)
    assert compile_timeout(50_000_000) == pytest.approx(1030.0)
    monkeypatch.setenv("UAVDYN_CC_TIMEOUT", "7")
    assert compile_timeout(50_000_000) == 7.0
