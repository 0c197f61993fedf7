"""Building a library into the compile cache, checking the build, and loading it verified."""

from __future__ import annotations

import contextlib
import json
import os
import struct
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable
from pathlib import Path

import casadi as ca

from uavdyn.integrate.compile_cache import (
    SIDECAR_FORMAT,
    CacheError,
    _sha256_fd,
    _sidecar,
    _signature,
    _verify_link,
)
from uavdyn.integrate.compiler import (
    TIMEOUT_ENV,
    CompileError,
    CompileTimeout,
    _compiler_id,
    compile_timeout,
)
from uavdyn.interrupts import reraise_interrupt

STALE_TEMP_SECONDS = 24 * 3600


def check_binary(path: str | Path) -> str | None:
    """Why ``path`` is not a complete shared library for this platform, or None.

    For ELF the header must say shared object (``ET_DYN``) and every header table and loadable
    segment must lie inside the file, so a truncated library is caught before ``dlopen`` maps it
    (mapping past the end of a file raises SIGBUS on first use).

    Parameters
    ----------
    path : path
        The candidate library.

    Returns
    -------
    str or None
        A short reason, or None when the file looks complete.
    """
    try:
        with open(path, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            head = fh.read(64)
            if size == 0:
                return "empty file"
            if head[:4] == b"\x7fELF":
                return _check_elf(fh, head, size)
    except OSError as exc:
        return f"cannot read: {exc.strerror or exc}"
    if sys.platform == "darwin" and head[:4] in (b"\xcf\xfa\xed\xfe", b"\xce\xfa\xed\xfe",
                                                  b"\xca\xfe\xba\xbe"):
        return None
    if sys.platform == "win32" and head[:2] == b"MZ":
        return None
    return "not a shared library (no ELF header)"


def _check_elf(fh, head: bytes, size: int) -> str | None:
    if len(head) < 52 or head[4] not in (1, 2) or head[5] not in (1, 2):
        return "truncated or malformed ELF header"
    end = "<" if head[5] == 1 else ">"
    is64 = head[4] == 2
    if is64 and len(head) < 64:
        return "truncated ELF header"
    (e_type,) = struct.unpack_from(end + "H", head, 16)
    if e_type != 3:
        return f"ELF type {e_type}, not a shared object"
    if is64:
        phoff, shoff = struct.unpack_from(end + "QQ", head, 32)
        phentsize, phnum, shentsize, shnum = struct.unpack_from(end + "HHHH", head, 54)
    else:
        phoff, shoff = struct.unpack_from(end + "II", head, 28)
        phentsize, phnum, shentsize, shnum = struct.unpack_from(end + "HHHH", head, 42)
    if phnum == 0 or phentsize < (56 if is64 else 32):
        return "ELF file without program headers"
    for offset, count, entsize in ((phoff, phnum, phentsize), (shoff, shnum, shentsize)):
        if offset + count * entsize > size:
            return f"truncated ({size} bytes; its ELF headers extend past the end)"
    fh.seek(phoff)
    table = fh.read(phnum * phentsize)
    for i in range(phnum):
        entry = table[i * phentsize:(i + 1) * phentsize]
        if is64:
            p_type, _, p_offset, _, _, p_filesz = struct.unpack_from(end + "IIQQQQ", entry)
        else:
            p_type, p_offset, _, _, p_filesz = struct.unpack_from(end + "IIIII", entry)
        if p_type == 1 and p_offset + p_filesz > size:  # PT_LOAD past the end: SIGBUS on use
            return f"truncated ({size} bytes; a loadable segment extends past the end)"
    return None


def _summary(stderr: str) -> str:
    """One line of the compiler's output for the message (the first error, else the last)."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    if not lines:
        return "no output"
    errors = [line for line in lines if "error" in line.lower()]
    line = (errors or lines[-1:])[0]
    return line if len(line) <= 200 else line[:197] + "..."


def run_compiler(cmd: list[str], timeout: float) -> subprocess.CompletedProcess:
    """Run a compiler command in its own process group, killed whole (with anything it
    started) after ``timeout`` seconds.

    Raises
    ------
    subprocess.TimeoutExpired
        If it did not finish in time.
    OSError
        If it cannot be started.
    """
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          stdin=subprocess.DEVNULL, start_new_session=True) as proc:
        try:
            out, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(OSError):
                os.killpg(proc.pid, 9)
            proc.communicate()
            raise
    return subprocess.CompletedProcess(cmd, proc.returncode, out.decode(errors="replace"),
                                       err.decode(errors="replace"))


def _build(source: Path, compiler: str, flags: tuple[str, ...], lib: Path, key: str, name: str,
           signature: list) -> None:
    """Compile to a unique temporary sibling, check it, then rename library and sidecar into
    place; on any failure nothing lands under the final names."""
    folder = lib.parent
    _remove_stale_temps(folder)
    fd, tmp_name = tempfile.mkstemp(dir=folder, prefix=f".{lib.name}.", suffix=".tmp")
    os.close(fd)
    partial = Path(tmp_name)
    side_tmp: Path | None = None
    cmd = [compiler, *flags, str(source), "-o", str(partial), "-lm"]
    err = {"compiler": compiler, "function": name, "command": cmd}
    try:
        timeout = compile_timeout(source.stat().st_size)
        try:
            proc = run_compiler(cmd, timeout)
        except subprocess.TimeoutExpired:
            raise CompileTimeout(f"compiler {compiler} did not finish CasADi Function '{name}' "
                                 f"within {timeout:.3g} s (killed; ${TIMEOUT_ENV} sets the "
                                 "limit)", **err) from None
        except OSError as exc:
            raise CompileError(f"cannot run compiler {compiler} for CasADi Function '{name}': "
                               f"{exc.strerror or exc}", **err) from None
        if proc.returncode != 0:
            status = (f"exit {proc.returncode}" if proc.returncode > 0
                      else f"killed by signal {-proc.returncode}")
            raise CompileError(f"compiler {compiler} failed on CasADi Function '{name}' "
                               f"({status}): {_summary(proc.stderr)}", returncode=proc.returncode,
                               stderr=proc.stderr, **err)
        bad = check_binary(partial)
        if bad:
            raise CompileError(f"compiler {compiler} exited 0 but its output for CasADi Function "
                               f"'{name}' is not a loadable library ({bad})", returncode=0,
                               stderr=proc.stderr, **err)
        os.chmod(partial, 0o700)
        _trial_load(partial, compiler, name, signature, err)
        fd = os.open(partial, os.O_RDONLY)
        try:
            digest, size = _sha256_fd(fd), os.fstat(fd).st_size
        finally:
            os.close(fd)
        record = {"format": SIDECAR_FORMAT, "library": lib.name, "sha256": digest, "size": size,
                  "key": key, "function": name, "compiler": compiler,
                  "compiler_id": _compiler_id(compiler), "flags": list(flags),
                  "casadi": ca.__version__, "signature": signature,
                  "built": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        fd, side_name = tempfile.mkstemp(dir=folder, prefix=f".{lib.name}.", suffix=".tmp")
        side_tmp = Path(side_name)
        with os.fdopen(fd, "w") as fh:
            json.dump(record, fh, indent=1)
            fh.flush()
            os.fsync(fh.fileno())
        try:
            os.replace(partial, lib)
            os.replace(side_tmp, _sidecar(lib))
        except OSError as exc:
            raise CacheError(f"cannot place the library for CasADi Function '{name}' at {lib}: "
                             f"{exc.strerror or exc}", lib, **err) from None
        _fsync_dir(folder)
    finally:
        for leftover in (partial, side_tmp):
            if leftover is not None:
                with contextlib.suppress(OSError):
                    leftover.unlink()


def _trial_load(partial: Path, compiler: str, name: str, signature: list, err: dict) -> None:
    """Load the fresh build once (under its unique temporary name) to check that CasADi finds
    the Function with the expected inputs and outputs."""
    try:
        trial = ca.external(name, str(partial))
    except RuntimeError as exc:
        reraise_interrupt(exc)
        raise CompileError(f"compiler {compiler} exited 0 but casadi.external cannot load its "
                           f"output for CasADi Function '{name}' ({_casadi_reason(exc)})",
                           returncode=0, **err) from None
    got = _signature(trial)
    del trial
    if got != signature:
        raise CompileError(f"compiler {compiler} exited 0 but its output for CasADi Function "
                           f"'{name}' has inputs/outputs {got}, expected {signature}",
                           returncode=0, **err)


def _load_verified(lib: Path, key: str, name: str, signature: list,
                   opener: Callable[[str, str], object] | None = None) -> ca.Function:
    """``casadi.external`` on a private hard link of ``lib`` verified just before ``dlopen``.

    The link pins the verified inode (a later replacement of ``lib`` cannot swap what is
    loaded) and gives every load a fresh name: the dynamic loader returns an already loaded
    object of the same name without reopening the file, which would otherwise hand back a stale
    mapping of an earlier library with this name. ``opener(name, path)`` loads it otherwise
    (e.g. with ``ctypes``, to call it on NumPy buffers without CasADi's conversions).
    """
    link = lib.with_name(f".{lib.name}.{os.getpid()}-{uuid.uuid4().hex[:12]}.load.tmp")
    try:
        os.link(lib, link)
    except OSError:  # no hard links here: verify and load the path itself (under the lock)
        link = lib
    try:
        reason = _verify_link(link, lib, key, name, signature)
        if reason is not None:
            raise CacheError(f"refusing library {lib} ({reason})", lib)
        try:
            loaded = (opener or ca.external)(name, str(link))
        except RuntimeError as exc:
            reraise_interrupt(exc)
            raise CacheError(f"verified library {lib} cannot be loaded "
                             f"({_casadi_reason(exc)})", lib) from None
    finally:
        if link != lib:
            with contextlib.suppress(OSError):
                link.unlink()
    if isinstance(loaded, ca.Function) and _signature(loaded) != signature:
        raise CacheError(f"library {lib} has other inputs/outputs than CasADi Function "
                         f"'{name}'", lib)
    return loaded


def _casadi_reason(exc: BaseException) -> str:
    """The informative line of a CasADi exception (they span several lines)."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    for line in lines:
        if "Cannot load" in line or "Could not find" in line:
            return line[:200]
    return (lines[-1] if lines else type(exc).__name__)[:200]


def _remove_stale_temps(folder: Path) -> None:
    """Drop temporaries left by a build or load that was killed (older than a day)."""
    cutoff = time.time() - STALE_TEMP_SECONDS
    for path in folder.glob(".*.tmp"):
        with contextlib.suppress(OSError):
            if os.lstat(path).st_mtime < cutoff:
                path.unlink()


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError, AttributeError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
