"""Compile any CasADi Function to C, build a shared library with the system compiler, and load
it back with ``casadi.external``; results are cached on disk by a hash of the generated source.

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
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shutil
import stat
import struct
import subprocess
import sys
import tempfile
import time
import uuid
import warnings
from collections.abc import Iterator
from pathlib import Path

import casadi as ca

try:  # POSIX only; elsewhere the cache stays correct (atomic renames) but may build twice
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

CACHE_ENV = "UAVDYN_CACHE"
COMPILER_ENV = "UAVDYN_CC"
DEFAULT_FLAGS = ("-O3", "-fPIC", "-shared")
SIDECAR_SUFFIX = ".sha256"
SIDECAR_FORMAT = 1
MAX_SIDECAR_BYTES = 64 * 1024
STALE_TEMP_SECONDS = 24 * 3600
_CHUNK = 1 << 20


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


class CacheError(CompileError):
    """The compile cache refused a folder or a library it cannot verify (``path`` names it)."""

    def __init__(self, message: str, path: str | Path | None = None, **kwargs) -> None:
        super().__init__(message, **kwargs)  # path optional: exceptions unpickle from args
        self.path = Path(path) if path is not None else None


_warned = False


def cache_dir() -> Path:
    """Where compiled libraries live: ``$UAVDYN_CACHE`` or the user cache folder.

    Returns
    -------
    Path
        The folder (not created here; :func:`compile_function` creates it with mode 0o700 and
        refuses it if it is world-writable or owned by another user).
    """
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "uavdyn"


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


def generate_c(func: ca.Function, directory: Path, name: str | None = None,
               with_header: bool = False, casadi_real: str = "double",
               with_jacobians: bool = False) -> Path:
    """Write the C source of ``func`` (and optionally its Jacobian and a header).

    Parameters
    ----------
    func : casadi.Function
        The Function.
    directory : Path
        Output folder (created if needed).
    name : str, optional
        Base name of the files (default ``func.name()``).
    with_header, casadi_real, with_jacobians
        Passed to ``casadi.CodeGenerator`` (header file, ``double``/``float``, Jacobian too).

    Returns
    -------
    Path
        The ``.c`` file.
    """
    name = name or func.name()
    opts = {"with_header": with_header, "casadi_real": casadi_real}
    gen = ca.CodeGenerator(f"{name}.c", opts)
    gen.add(func)
    if with_jacobians:
        gen.add(func.jacobian())
    directory.mkdir(parents=True, exist_ok=True)
    gen.generate(str(directory) + os.sep)
    return directory / f"{name}.c"


def library_path(func: ca.Function, flags: tuple[str, ...] = DEFAULT_FLAGS,
                 directory: str | Path | None = None, compiler: str | None = None) -> Path:
    """The cache path the compiled library of ``func`` has (whether or not it exists yet).

    Parameters
    ----------
    func : casadi.Function
        The Function to compile.
    flags : tuple of str
        Compiler flags (part of the cache key).
    directory : path, optional
        Cache folder (default :func:`cache_dir`).
    compiler : str, optional
        Compiler executable (default :func:`find_compiler`).

    Returns
    -------
    Path
        ``<folder>/<name>_<key>.so``; its sidecar is the same path plus ``.sha256``.

    Raises
    ------
    CompileError
        If no compiler is given or found.
    """
    folder = Path(directory) if directory else cache_dir()
    key = cache_key(func, flags, compiler)
    return _lib_for(folder.expanduser().absolute(), func.name(), key)


def cache_key(func: ca.Function, flags: tuple[str, ...] = DEFAULT_FLAGS,
              compiler: str | None = None) -> str:
    """The full cache key of ``func``: SHA-256 of its generated C source, the compiler
    (resolved path, size, modification time), the flags, the CasADi version and the platform.

    Parameters
    ----------
    func : casadi.Function
        The Function to compile.
    flags : tuple of str
        Compiler flags.
    compiler : str, optional
        Compiler executable (default :func:`find_compiler`).

    Returns
    -------
    str
        64 hex digits; the library name carries the first 20, the sidecar all of them.

    Raises
    ------
    CompileError
        If no compiler is given or found.
    """
    compiler = compiler or find_compiler()
    if compiler is None:
        raise CompileError("no C compiler found (cc/gcc/clang or $UAVDYN_CC)")
    with tempfile.TemporaryDirectory() as tmp:
        source = generate_c(func, Path(tmp), func.name())
        return _source_key(source.read_bytes(), compiler, flags)


def compile_function(func: ca.Function, flags: tuple[str, ...] = DEFAULT_FLAGS,
                     directory: str | Path | None = None, warn: bool = True) -> ca.Function:
    """Return a compiled equivalent of ``func`` (same name, inputs and outputs).

    The generated source is hashed together with the compiler, flags and CasADi version; a
    library already built for that hash is reused only after its SHA-256 matches the sidecar
    written by the build that produced it. If no compiler is available, ``func`` itself is
    returned and a :class:`CodegenWarning` is issued once per process.

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
        source = generate_c(func, Path(tmp), name)
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
                except CompileError as exc:
                    if reason == _ABSENT:
                        raise
                    raise CacheError(f"refusing unverified library {lib} ({reason}); rebuilding "
                                     f"it failed: {exc}", lib, compiler=exc.compiler,
                                     function=name, command=exc.command,
                                     returncode=exc.returncode, stderr=exc.stderr) from None
            return _load_verified(lib, key, name, signature)


_DECLARED = re.compile(r"^void (\w+)_incref\(void\);$", re.MULTILINE)


def _external_calls(source: str) -> list[str]:
    """Functions the generated source declares but does not define (compiled ``External``
    Functions called from the graph)."""
    return sorted(n for n in set(_DECLARED.findall(source))
                  if f"void {n}_incref(void) {{" not in source)


# -- cache folder ------------------------------------------------------------------------------

def _prepare_folder(folder: Path) -> Path:
    """Create the cache folder (0o700) and refuse one that others could write into: a library
    planted there would run its code in our process on ``dlopen``."""
    folder = folder.expanduser().absolute()
    try:
        if not os.path.lexists(folder):
            folder.mkdir(mode=0o700, parents=True, exist_ok=True)
        st = os.stat(folder)
    except OSError as exc:
        raise CacheError(f"cannot use compile cache folder {folder}: "
                         f"{exc.strerror or exc}", folder) from None
    if not stat.S_ISDIR(st.st_mode):
        raise CacheError(f"compile cache folder {folder} is not a folder", folder)
    uid = os.getuid() if hasattr(os, "getuid") else None
    if uid is not None and st.st_uid != uid:
        raise CacheError(f"refusing compile cache folder {folder}: owned by uid {st.st_uid}, not "
                         f"by this user (uid {uid}); set ${CACHE_ENV} to a private folder", folder)
    if st.st_mode & stat.S_IWOTH:
        raise CacheError(f"refusing compile cache folder {folder}: it is world-writable (mode "
                         f"{stat.S_IMODE(st.st_mode):04o}); chmod 700 it or set ${CACHE_ENV} to a "
                         "private folder", folder)
    return folder


@contextlib.contextmanager
def _locked(lock_path: Path) -> Iterator[None]:
    """Hold an exclusive ``flock`` on ``lock_path`` (one per library): serialises builds and
    verified loads of one library across threads (each call opens its own file description)
    and processes."""
    if fcntl is None:  # pragma: no cover
        yield
        return
    flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(lock_path, flags, 0o600)
    except OSError as exc:
        raise CacheError(f"cannot open lock file {lock_path}: {exc.strerror or exc}",
                         lock_path) from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError:  # a filesystem without flock: still correct, maybe built twice
            pass
        yield
    finally:
        os.close(fd)


# -- keys, signatures, verification ------------------------------------------------------------

_ABSENT = "absent"


def _compiler_id(compiler: str) -> str:
    """The compiler's resolved path, size and modification time: an upgraded compiler gets new
    cache keys without having to run it."""
    real = os.path.realpath(compiler)
    try:
        st = os.stat(real)
    except OSError:
        return real
    return f"{real}:{st.st_size}:{st.st_mtime_ns}"


def _source_key(source: bytes, compiler: str, flags: tuple[str, ...]) -> str:
    digest = hashlib.sha256(source)
    for part in (_compiler_id(compiler), " ".join(flags), ca.__version__, sys.platform):
        digest.update(b"\n" + part.encode())
    return digest.hexdigest()


def _lib_for(folder: Path, name: str, key: str) -> Path:
    return folder / f"{name}_{key[:20]}.so"


def _sidecar(lib: Path) -> Path:
    return lib.with_name(lib.name + SIDECAR_SUFFIX)


def _signature(func: ca.Function) -> list:
    """Inputs and outputs as ``[[rows, cols, nnz], ...]`` per side (JSON-comparable)."""
    def dims(sp: ca.Sparsity) -> list[int]:
        return [int(sp.size1()), int(sp.size2()), int(sp.nnz())]
    return [[dims(func.sparsity_in(i)) for i in range(func.n_in())],
            [dims(func.sparsity_out(i)) for i in range(func.n_out())]]


def _sha256_fd(fd: int) -> str:
    digest = hashlib.sha256()
    os.lseek(fd, 0, os.SEEK_SET)
    while chunk := os.read(fd, _CHUNK):
        digest.update(chunk)
    return digest.hexdigest()


def _read_sidecar(lib: Path) -> dict | str:
    """The sidecar's record, or a reason it is unusable (never blocks on a FIFO)."""
    path = _sidecar(lib)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return "no sidecar: not built by this cache"
    except OSError as exc:
        return f"sidecar unreadable: {exc.strerror or exc}"
    if not stat.S_ISREG(st.st_mode):
        return "sidecar is not a regular file"
    if st.st_size > MAX_SIDECAR_BYTES:
        return "sidecar too large"
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0)
                     | getattr(os, "O_NONBLOCK", 0))
        try:
            raw = os.read(fd, MAX_SIDECAR_BYTES + 1)
        finally:
            os.close(fd)
        record = json.loads(raw.decode("utf-8"))
    except (OSError, ValueError, RecursionError):
        return "sidecar is not valid JSON"
    if not isinstance(record, dict):
        return "sidecar is not a JSON object"
    return record


def _check_record(record: dict, lib: Path, key: str, name: str, signature: list) -> str | None:
    expected = {"format": SIDECAR_FORMAT, "library": lib.name, "key": key, "function": name,
                "casadi": ca.__version__, "signature": signature}
    for field, value in expected.items():
        if record.get(field) != value:
            what = "source" if field == "key" else field
            return f"sidecar records another {what}"
    if not isinstance(record.get("sha256"), str) or not isinstance(record.get("size"), int):
        return "sidecar lacks the library's SHA-256"
    return None


def _verify(lib: Path, key: str, name: str, signature: list) -> str | None:
    """None if ``lib`` is a verified build of ``key``; else why not (without opening it for
    execution)."""
    try:
        st = os.lstat(lib)
    except FileNotFoundError:
        return _ABSENT
    except OSError as exc:
        return f"cannot stat: {exc.strerror or exc}"
    reason = _check_file(st)
    if reason:
        return reason
    record = _read_sidecar(lib)
    if isinstance(record, str):
        return record
    reason = _check_record(record, lib, key, name, signature)
    if reason:
        return reason
    if record["size"] != st.st_size:
        return "size differs from its sidecar"
    return _digest_reason(lib, record, check_file=False)


def _check_file(st: os.stat_result) -> str | None:
    if not stat.S_ISREG(st.st_mode):
        return "not a regular file"
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        return f"owned by uid {st.st_uid}"
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return "writable by others"
    if st.st_size == 0:
        return "empty"
    return None


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


# -- build and load ----------------------------------------------------------------------------

def _summary(stderr: str) -> str:
    """One line of the compiler's output for the message (the first error, else the last)."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    if not lines:
        return "no output"
    errors = [line for line in lines if "error" in line.lower()]
    line = (errors or lines[-1:])[0]
    return line if len(line) <= 200 else line[:197] + "..."


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
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, errors="replace",
                                  stdin=subprocess.DEVNULL)
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
        raise CompileError(f"compiler {compiler} exited 0 but casadi.external cannot load its "
                           f"output for CasADi Function '{name}' ({_casadi_reason(exc)})",
                           returncode=0, **err) from None
    got = _signature(trial)
    del trial
    if got != signature:
        raise CompileError(f"compiler {compiler} exited 0 but its output for CasADi Function "
                           f"'{name}' has inputs/outputs {got}, expected {signature}",
                           returncode=0, **err)


def _load_verified(lib: Path, key: str, name: str, signature: list) -> ca.Function:
    """``casadi.external`` on a private hard link of ``lib`` verified just before ``dlopen``.

    The link pins the verified inode (a later replacement of ``lib`` cannot swap what is
    loaded) and gives every load a fresh name: the dynamic loader returns an already loaded
    object of the same name without reopening the file, which would otherwise hand back a stale
    mapping of an earlier library with this name.
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
            loaded = ca.external(name, str(link))
        except RuntimeError as exc:
            raise CacheError(f"verified library {lib} cannot be loaded "
                             f"({_casadi_reason(exc)})", lib) from None
    finally:
        if link != lib:
            with contextlib.suppress(OSError):
                link.unlink()
    if _signature(loaded) != signature:
        raise CacheError(f"library {lib} has other inputs/outputs than CasADi Function "
                         f"'{name}'", lib)
    return loaded


def _verify_link(link: Path, lib: Path, key: str, name: str, signature: list) -> str | None:
    if link == lib:
        return _verify(lib, key, name, signature)
    # the sidecar is looked up by the library's own name; the content hashed is the link's
    record = _read_sidecar(lib)
    if isinstance(record, str):
        return record
    reason = _check_record(record, lib, key, name, signature)
    if reason:
        return reason
    return _digest_reason(link, record, check_file=True)


def _digest_reason(path: Path, record: dict, check_file: bool) -> str | None:
    """Why the file at ``path`` (never followed if a link) does not match its sidecar's
    SHA-256, or None; ``check_file`` re-checks the opened file's type, owner and mode."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
        try:
            if check_file:
                reason = _check_file(os.fstat(fd))
                if reason:
                    return reason
            digest = _sha256_fd(fd)
        finally:
            os.close(fd)
    except OSError as exc:
        return f"cannot read: {exc.strerror or exc}"
    if digest != record["sha256"]:
        return "SHA-256 differs from its sidecar"
    return None


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
