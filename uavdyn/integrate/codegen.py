"""Compile any CasADi Function to C, build a shared library with the system compiler, and load
it back with ``casadi.external``; results are cached on disk by a hash of the generated source.

Without a C compiler the CasADi VM is used instead, with one clear warning per process.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path

import casadi as ca

CACHE_ENV = "UAVDYN_CACHE"
COMPILER_ENV = "UAVDYN_CC"
DEFAULT_FLAGS = ("-O3", "-fPIC", "-shared")


class CodegenWarning(UserWarning):
    """Compilation was not possible; the uncompiled CasADi Function is used."""


class CompileError(RuntimeError):
    """The system compiler rejected the generated code."""


_warned = False


def cache_dir() -> Path:
    """Where compiled libraries live: ``$UAVDYN_CACHE`` or the user cache folder."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "uavdyn"


def find_compiler() -> str | None:
    """The C compiler to use: ``$UAVDYN_CC`` if set (empty means none), else cc or gcc/clang."""
    env = os.environ.get(COMPILER_ENV)
    if env is not None:
        return shutil.which(env) if env else None
    for name in ("cc", "gcc", "clang"):
        path = shutil.which(name)
        if path:
            return path
    return None


def generate_c(func: ca.Function, directory: Path, name: str | None = None,
               with_header: bool = False, casadi_real: str = "double",
               with_jacobians: bool = False) -> Path:
    """Write the C source of ``func`` (and optionally its Jacobian and a header)."""
    name = name or func.name()
    opts = {"with_header": with_header, "casadi_real": casadi_real}
    gen = ca.CodeGenerator(f"{name}.c", opts)
    gen.add(func)
    if with_jacobians:
        gen.add(func.jacobian())
    directory.mkdir(parents=True, exist_ok=True)
    gen.generate(str(directory) + os.sep)
    return directory / f"{name}.c"


def compile_function(func: ca.Function, flags: tuple[str, ...] = DEFAULT_FLAGS,
                     directory: str | Path | None = None, warn: bool = True) -> ca.Function:
    """Return a compiled equivalent of ``func`` (same name, inputs and outputs).

    The generated source is hashed together with the compiler flags and CasADi version; a
    library already built for that hash is reused. If no compiler is available, ``func`` itself
    is returned and a :class:`CodegenWarning` is issued once.
    """
    global _warned
    compiler = find_compiler()
    if compiler is None:
        if warn and not _warned:
            warnings.warn("no C compiler found (cc/gcc/clang or $UAVDYN_CC); using the CasADi "
                          "virtual machine instead of compiled code (about 3x slower)",
                          CodegenWarning, stacklevel=2)
            _warned = True
        return func
    name = func.name()
    with tempfile.TemporaryDirectory() as tmp:
        source = generate_c(func, Path(tmp), name)
        text = source.read_text()
        key = hashlib.sha256(
            "\n".join([text, compiler, " ".join(flags), ca.__version__]).encode()
        ).hexdigest()[:20]
        target_dir = Path(directory) if directory else cache_dir()
        target_dir.mkdir(parents=True, exist_ok=True)
        lib = target_dir / f"{name}_{key}.so"
        if not lib.exists():
            partial = target_dir / f".{lib.name}.{os.getpid()}.tmp"
            cmd = [compiler, *flags, str(source), "-o", str(partial), "-lm"]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                raise CompileError(f"compiling {name} failed ({' '.join(cmd)}):\n"
                                   f"{proc.stderr[-2000:]}")
            os.replace(partial, lib)  # atomic: a concurrent reader never sees half a library
    return ca.external(name, str(lib))
