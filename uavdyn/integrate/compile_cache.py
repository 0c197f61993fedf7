"""The verified on-disk cache of compiled libraries: its folder, keys, sidecars and checks."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import stat
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import casadi as ca

from uavdyn.integrate.compiler import DEFAULT_FLAGS, CompileError, _compiler_id, find_compiler
from uavdyn.integrate.csource import generate_c

try:  # POSIX only; elsewhere the cache stays correct (atomic renames) but may build twice
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

CACHE_ENV = "UAVDYN_CACHE"
SIDECAR_SUFFIX = ".sha256"
SIDECAR_FORMAT = 1
MAX_SIDECAR_BYTES = 64 * 1024
_CHUNK = 1 << 20
_ABSENT = "absent"


class CacheError(CompileError):
    """The compile cache refused a folder or a library it cannot verify (``path`` names it)."""

    def __init__(self, message: str, path: str | Path | None = None, **kwargs) -> None:
        super().__init__(message, **kwargs)  # path optional: exceptions unpickle from args
        self.path = Path(path) if path is not None else None


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


def _checked_record(lib: Path, key: str, name: str, signature: list) -> dict | str:
    """The sidecar's record of ``lib`` if it is readable and records this key, Function, CasADi
    version and signature; else why not."""
    record = _read_sidecar(lib)
    if isinstance(record, str):
        return record
    return _check_record(record, lib, key, name, signature) or record


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
    record = _checked_record(lib, key, name, signature)
    if isinstance(record, str):
        return record
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


def _verify_link(link: Path, lib: Path, key: str, name: str, signature: list) -> str | None:
    if link == lib:
        return _verify(lib, key, name, signature)
    # the sidecar is looked up by the library's own name; the content hashed is the link's
    record = _checked_record(lib, key, name, signature)
    if isinstance(record, str):
        return record
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
