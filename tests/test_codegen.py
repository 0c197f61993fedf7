"""Code generation: compiled functions equal the VM, are cached by content, and degrade to the
VM with one warning when there is no compiler."""

import warnings

import numpy as np
import pytest

import uavdyn.integrate.codegen as codegen
from uavdyn.model import build_model


@pytest.mark.skipif(codegen.find_compiler() is None, reason="no C compiler")
def test_compiled_function_cached_by_content(tmp_path, monkeypatch, aerosonde, aerosonde_trim):
    monkeypatch.setenv(codegen.CACHE_ENV, str(tmp_path))
    f = build_model(aerosonde).f
    c1 = codegen.compile_function(f)
    libs = sorted(tmp_path.glob("*.so"))
    assert len(libs) == 1
    mtime = libs[0].stat().st_mtime_ns
    c2 = codegen.compile_function(f)
    assert sorted(tmp_path.glob("*.so")) == libs and libs[0].stat().st_mtime_ns == mtime
    x, u = aerosonde_trim.x + [1.0, 0.5, 0.1, 0.0], aerosonde_trim.u
    for c in (c1, c2):
        np.testing.assert_allclose(np.array(c(x, u, aerosonde.p)),
                                   np.array(f(x, u, aerosonde.p)), rtol=0, atol=1e-12)
    # a different function gets a different library
    codegen.compile_function(build_model(aerosonde).jacobians)
    assert len(list(tmp_path.glob("*.so"))) == 2


def test_no_compiler_falls_back_to_vm_with_one_warning(monkeypatch, aerosonde):
    monkeypatch.setenv(codegen.COMPILER_ENV, "")
    monkeypatch.setattr(codegen, "_warned", False)
    f = build_model(aerosonde).f
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        g = codegen.compile_function(f)
        h = codegen.compile_function(f)
    assert g is f and h is f
    msgs = [w for w in caught if issubclass(w.category, codegen.CodegenWarning)]
    assert len(msgs) == 1 and "no C compiler found" in str(msgs[0].message)


def test_compile_error_is_reported(monkeypatch, tmp_path, aerosonde):
    fake = tmp_path / "badcc"
    fake.write_text("#!/bin/sh\necho 'simulated compiler failure' >&2\nexit 1\n")
    fake.chmod(0o755)
    monkeypatch.setenv(codegen.COMPILER_ENV, str(fake))
    monkeypatch.setenv(codegen.CACHE_ENV, str(tmp_path / "cache"))
    with pytest.raises(codegen.CompileError, match="simulated compiler failure"):
        codegen.compile_function(build_model(aerosonde).f)
