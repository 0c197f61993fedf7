"""Compiled CasADi Functions: C code, a shared library, loaded back from a verified disk cache.

Any CasADi Function is compiled to C, built into a shared library with the system compiler, and
loaded back with ``casadi.external``; results are cached on disk by a hash of the generated
source.

The cache loads only what it can verify. A library is placed under its final name only after a
successful build whose output is a complete shared object that ``casadi.external`` loads with the
expected inputs and outputs; a sidecar ``<library>.sha256`` (JSON) then records the library's
own SHA-256, the source hash, compiler, flags and CasADi version. Before every ``dlopen`` the
library's SHA-256 is recomputed and compared with its sidecar; anything else found under a cache
name (a foreign, truncated or tampered library, or one without a sidecar) is never loaded but
rebuilt, or refused with :class:`CacheError` when it cannot be rebuilt. A cache folder that is
world-writable or owned by another user is refused. Builds go to unique temporary names and are
renamed into place (``os.replace``) under a per-library ``flock``, so threads and processes may
compile the same Function concurrently.

Without a C compiler the CasADi VM is used instead, with one clear warning per process.

This module holds :func:`compile_function`; the parts live in :mod:`uavdyn.integrate.compiler`
(finding the compiler), :mod:`uavdyn.integrate.csource` (C generation),
:mod:`uavdyn.integrate.compile_cache` (folder, keys, sidecars, verification) and
:mod:`uavdyn.integrate.library_build` (build, checks, verified load); every name is re-exported
here.
"""

from __future__ import annotations

import tempfile
import warnings
from collections.abc import Callable
from collections.abc import Iterator as Iterator
from pathlib import Path

import casadi as ca

from uavdyn.integrate.compile_cache import (
    _ABSENT,
    CACHE_ENV,
    MAX_SIDECAR_BYTES,
    SIDECAR_FORMAT,
    SIDECAR_SUFFIX,
    CacheError,
    _lib_for,
    _locked,
    _prepare_folder,
    _signature,
    _source_key,
    _verify,
    cache_dir,
    cache_key,
    library_path,
)
from uavdyn.integrate.compile_cache import _CHUNK as _CHUNK
from uavdyn.integrate.compile_cache import _check_file as _check_file
from uavdyn.integrate.compile_cache import _check_record as _check_record
from uavdyn.integrate.compile_cache import _checked_record as _checked_record
from uavdyn.integrate.compile_cache import _digest_reason as _digest_reason
from uavdyn.integrate.compile_cache import _read_sidecar as _read_sidecar
from uavdyn.integrate.compile_cache import _sha256_fd as _sha256_fd
from uavdyn.integrate.compile_cache import _sidecar as _sidecar
from uavdyn.integrate.compile_cache import _verify_link as _verify_link
from uavdyn.integrate.compiler import (
    COMPILER_ENV,
    DEFAULT_FLAGS,
    CodegenWarning,
    CompileError,
    CompileTimeout,
    find_compiler,
)
from uavdyn.integrate.compiler import _compiler_id as _compiler_id
from uavdyn.integrate.csource import _DECLARED as _DECLARED
from uavdyn.integrate.csource import _external_calls, generate_c
from uavdyn.integrate.library_build import STALE_TEMP_SECONDS, _build, _load_verified, check_binary
from uavdyn.integrate.library_build import _casadi_reason as _casadi_reason
from uavdyn.integrate.library_build import _check_elf as _check_elf
from uavdyn.integrate.library_build import _fsync_dir as _fsync_dir
from uavdyn.integrate.library_build import _remove_stale_temps as _remove_stale_temps
from uavdyn.integrate.library_build import _summary as _summary
from uavdyn.integrate.library_build import _trial_load as _trial_load

__all__ = ["CACHE_ENV", "COMPILER_ENV", "DEFAULT_FLAGS", "MAX_SIDECAR_BYTES", "SIDECAR_FORMAT",
           "SIDECAR_SUFFIX", "STALE_TEMP_SECONDS", "CacheError", "CodegenWarning", "CompileError",
           "cache_dir", "cache_key", "check_binary", "compile_function", "find_compiler",
           "generate_c", "library_path"]
# The private names of this module from before it was split stay importable from it (the
# ``as`` imports). Tests patch ``_build`` and ``_warned`` here: compile_function looks both up
# in this module's globals.

_warned = False
_timed_out: dict[str, str] = {}  # compiler -> the message of its timeout in this process


def compile_function(func: ca.Function, flags: tuple[str, ...] = DEFAULT_FLAGS,
                     directory: str | Path | None = None, warn: bool = True,
                     source: Callable[[Path, str], Path] | None = None,
                     opener: Callable[[str, str], object] | None = None) -> ca.Function:
    """Return a compiled equivalent of ``func`` (same name, inputs and outputs).

    The generated source is hashed together with the compiler, flags and CasADi version; a
    library already built for that hash is reused only after its SHA-256 matches the sidecar
    written by the build that produced it. If no compiler is available, ``func`` itself is
    returned and a :class:`CodegenWarning` is issued once per process; so it is when the
    compiler does not finish within its time limit (:func:`compile_timeout`: 30 s plus 20 s per
    MB of generated C, or ``$UAVDYN_CC_TIMEOUT``),
    and that compiler is not called again in this process.

    Parameters
    ----------
    func : casadi.Function
        Any CasADi Function (SX or MX).
    flags : tuple of str
        Compiler flags; the source file, ``-o`` and ``-lm`` are added.
    directory : path, optional
        Cache folder (default :func:`cache_dir`); created with mode 0o700.
    warn : bool
        Whether to warn (once) when falling back to the VM.
    source : callable, optional
        ``source(folder, name) -> path`` writes the C source of an equivalent of ``func`` under
        ``name`` into ``folder`` (default: CasADi's code generation of ``func``); the library
        is checked against ``func``'s inputs and outputs all the same.
    opener : callable, optional
        ``opener(name, path)`` loads the verified library instead of ``casadi.external`` (and
        is what is returned; ``func`` itself still without a compiler).

    Returns
    -------
    casadi.Function
        An ``External`` Function loaded from the verified library, or ``func`` without compiler.

    Raises
    ------
    CompileError
        The compiler failed, or its output is not a loadable library with ``func``'s inputs
        and outputs (one line naming the compiler and the Function; ``.stderr`` has the rest).
    CacheError
        The cache folder is world-writable, foreign-owned or not a folder; or an unverifiable
        library occupies the cache name and cannot be rebuilt or replaced.
    """
    global _warned
    compiler = find_compiler()
    if compiler in _timed_out:
        return func
    if compiler is None:
        if warn and not _warned:
            warnings.warn("no C compiler found (cc/gcc/clang or $UAVDYN_CC); using the CasADi "
                          "virtual machine instead of compiled code (about 3x slower)",
                          CodegenWarning, stacklevel=2)
            _warned = True
        return func
    name = func.name()
    folder = _prepare_folder(Path(directory) if directory else cache_dir())
    signature = _signature(func)
    with tempfile.TemporaryDirectory() as tmp:
        source = (source or (lambda folder, n: generate_c(func, folder, n)))(Path(tmp), name)
        external = _external_calls(source.read_text(errors="replace"))
        if external:
            # the generated C would call a function living in another library: loading it
            # fails at call time with an unresolved symbol, which kills the process
            raise CompileError(
                f"cannot compile '{name}': it calls the already compiled Function(s) "
                f"{', '.join(external)}; compile the uncompiled expression instead (e.g. "
                "hybrid_step(..., compile=False))", compiler=compiler, function=name)
        key = _source_key(source.read_bytes(), compiler, flags)
        lib = _lib_for(folder, name, key)
        with _locked(folder / f".{lib.name}.lock"):
            reason = _verify(lib, key, name, signature)
            if reason is not None:
                try:
                    _build(source, compiler, flags, lib, key, name, signature)
                except CompileTimeout as exc:
                    _timed_out[compiler] = str(exc)
                    warnings.warn(f"{exc}; using the CasADi virtual machine instead of compiled "
                                  "code", CodegenWarning, stacklevel=2)
                    return func
                except CompileError as exc:
                    if reason == _ABSENT:
                        raise
                    raise CacheError(f"refusing unverified library {lib} ({reason}); rebuilding "
                                     f"it failed: {exc}", lib, compiler=exc.compiler,
                                     function=name, command=exc.command,
                                     returncode=exc.returncode, stderr=exc.stderr) from None
            return _load_verified(lib, key, name, signature, opener)
