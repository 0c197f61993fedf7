"""The system C compiler: finding it, naming it in cache keys, and the errors of using it."""

from __future__ import annotations

import os
import shutil

COMPILER_ENV = "UAVDYN_CC"
TIMEOUT_ENV = "UAVDYN_CC_TIMEOUT"
# Without $UAVDYN_CC_TIMEOUT a build may take this long plus TIMEOUT_PER_MB per megabyte of
# generated C: a step or a rollout (kilobytes) gets half a minute, the identification's large
# sources (tens of MB) proportionally more.
DEFAULT_TIMEOUT_S = 30.0
TIMEOUT_PER_MB = 20.0
# Hidden by default, so the generated helpers (casadi_sq, a loop's step) can be inlined: in a
# shared library a visible function may be interposed and is called through the PLT, which
# made a compiled step 15-20 % slower than the same code in an executable. The entry points
# CasADi's code marks CASADI_SYMBOL_EXPORT (the interface casadi.external loads) stay visible.
HIDDEN_HELPERS = ("-fvisibility=hidden",
                  '-DCASADI_SYMBOL_EXPORT=__attribute__((visibility("default")))')
DEFAULT_FLAGS = ("-O3", "-fPIC", "-shared", *HIDDEN_HELPERS)
# for long generated code called a few thousand times (fits, derivatives): -O1 compiles in a
# fraction of -O3's time and ran as fast there
QUICK_FLAGS = ("-O1", "-fPIC", "-shared", *HIDDEN_HELPERS)


class CodegenWarning(UserWarning):
    """Compilation was not possible; the uncompiled CasADi Function is used."""


class CompileError(RuntimeError):
    """The system compiler rejected the generated code or produced no usable library.

    The message is one line naming the compiler and the Function; the full compiler output is
    kept in :attr:`stderr` (and shown as a note in tracebacks, e.g. with ``--debug``).

    Attributes
    ----------
    compiler, function : str or None
        The compiler executable and the CasADi Function's name.
    command : list of str or None
        The compiler command line.
    returncode : int or None
        The compiler's exit status.
    stderr : str
        The compiler's complete standard error.
    """

    def __init__(self, message: str, *, compiler: str | None = None,
                 function: str | None = None, command: list[str] | None = None,
                 returncode: int | None = None, stderr: str = "") -> None:
        super().__init__(message)
        self.compiler = compiler
        self.function = function
        self.command = command
        self.returncode = returncode
        self.stderr = stderr
        if stderr.strip() and hasattr(self, "add_note"):  # Python >= 3.11
            self.add_note(f"compiler output:\n{stderr.rstrip()}")


class CompileTimeout(CompileError):
    """The compiler did not finish within :func:`compile_timeout` seconds (it was killed)."""


def compile_timeout(source_bytes: int = 0) -> float:
    """Seconds a compiler call may take: ``$UAVDYN_CC_TIMEOUT`` if set to a positive number,
    else :data:`DEFAULT_TIMEOUT_S` plus :data:`TIMEOUT_PER_MB` per megabyte of the generated
    source (``source_bytes``).

    Raises
    ------
    ValueError
        If ``$UAVDYN_CC_TIMEOUT`` is set but not a positive number of seconds.
    """
    raw = os.environ.get(TIMEOUT_ENV)
    if raw is None or not raw.strip():
        return DEFAULT_TIMEOUT_S + TIMEOUT_PER_MB * source_bytes / 1e6
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not (value > 0 and value < float("inf")):
        raise ValueError(f"environment variable {TIMEOUT_ENV} must be a positive number of "
                         f"seconds, got {raw!r}")
    return value


def find_compiler() -> str | None:
    """The C compiler to use: ``$UAVDYN_CC`` if set (empty means none), else cc or gcc/clang.

    Returns
    -------
    str or None
        Full path of the executable, or None (the CasADi VM is then used).
    """
    env = os.environ.get(COMPILER_ENV)
    if env is not None:
        return shutil.which(env) if env else None
    for name in ("cc", "gcc", "clang"):
        path = shutil.which(name)
        if path:
            return path
    return None


def _compiler_id(compiler: str) -> str:
    """The compiler's resolved path, size and modification time: an upgraded compiler gets new
    cache keys without having to run it."""
    real = os.path.realpath(compiler)
    try:
        st = os.stat(real)
    except OSError:
        return real
    return f"{real}:{st.st_size}:{st.st_mtime_ns}"
