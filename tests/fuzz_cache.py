"""Malformed compile-cache inputs (run by ``tests/test_fuzz.py``): unsafe cache folders,
compilers that fail or exit 0 with unusable output, and libraries under a cache name that no
successful build of this source produced (poisoned, truncated, foreign, tampered sidecar).

The cache rebuilds an unverifiable library when it can, so every library case here pairs it
with a compiler that fails: the library must then be refused with :class:`CacheError` (never
loaded). The rebuild path, and that a poisoned library's constructor never runs, are asserted
in ``tests/test_codegen_cache.py``. The helpers below are shared with that file.
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import json
import os
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

import casadi as ca
from fuzz_common import Case

from uavdyn.integrate import codegen
from uavdyn.integrate.codegen import CacheError, CompileError

FUNCTION = "fuzz_cache_f"


def small_function(name: str = FUNCTION, n: int = 3) -> ca.Function:
    """A Function that compiles in a fraction of a second."""
    x = ca.SX.sym("x", n)
    return ca.Function(name, [x], [2 * ca.sin(x) + ca.sumsqr(x)], ["x"], ["y"])


def real_compiler() -> str | None:
    """The system compiler regardless of ``$UAVDYN_CC``."""
    for name in ("cc", "gcc", "clang"):
        path = shutil.which(name)
        if path:
            return path
    return None


@contextlib.contextmanager
def cache_env(cache: Path, compiler: str | Path | None = None) -> Iterator[None]:
    """Point the cache (and optionally the compiler) elsewhere for the duration of a call."""
    saved = {k: os.environ.get(k) for k in (codegen.CACHE_ENV, codegen.COMPILER_ENV)}
    os.environ[codegen.CACHE_ENV] = str(cache)
    if compiler is None:
        os.environ.pop(codegen.COMPILER_ENV, None)
    else:
        os.environ[codegen.COMPILER_ENV] = str(compiler)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def write_script(folder: Path, name: str, body: str) -> Path:
    """An executable ``/bin/sh`` script posing as a compiler; ``$out`` is its ``-o`` argument."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text("#!/bin/sh\nout=''\nfor a in \"$@\"; do\n  if [ \"$prev\" = '-o' ]; then "
                    "out=\"$a\"; fi\n  prev=\"$a\"\ndone\n" + body + "\n")
    path.chmod(0o755)
    return path


def failing_compiler(folder: Path) -> Path:
    return write_script(folder, "cc-fail", "echo 'fake.c:1:1: error: simulated failure' >&2\n"
                                           "echo 'second line of compiler output' >&2\nexit 1")


def garbage_compiler(folder: Path) -> Path:
    return write_script(folder, "cc-garbage", "echo 'this is not a shared library' > \"$out\"\n"
                                              "exit 0")


def compile_c(source: str, out: Path, *extra: str) -> Path:
    """Build a shared library from C text with the real compiler."""
    cc = real_compiler()
    assert cc is not None
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "lib.c"
        src.write_text(source)
        flags = [] if "-no-pie" in extra else ["-shared", "-fPIC"]
        subprocess.run([cc, *flags, *extra, str(src), "-o", str(out)], check=True,
                       capture_output=True)
    return out


def poison_library(out: Path, marker: Path) -> Path:
    """A valid shared library whose constructor writes ``marker`` as soon as it is dlopened."""
    text = ('#include <stdio.h>\n'
            '__attribute__((constructor)) static void poison(void) {\n'
            f'  FILE *f = fopen("{marker}", "w");\n'
            '  if (f) { fputs("loaded", f); fclose(f); }\n}\n'
            'int fuzz_cache_f_n_in(void) { return 1; }\n')
    return compile_c(text, out)


def genuine_library(folder: Path, func: ca.Function | None = None) -> Path:
    """A real cache build of ``func`` (default the small Function) in ``folder``; returns it."""
    func = func or small_function()
    with cache_env(folder):
        codegen.compile_function(func)
    return codegen.library_path(func, directory=folder, compiler=real_compiler())


def expected_library(cache: Path, compiler: Path) -> Path:
    return codegen.library_path(small_function(), directory=cache, compiler=str(compiler))


def _load(compiler: str | None):
    """``load(cache)``: compile the small Function into ``cache`` with the named script from the
    case folder as the compiler (None: the real one)."""
    def load(cache: Path) -> object:
        cc = None
        if compiler is not None:  # the script lives in the case folder, above the cache
            cc = next((p / compiler for p in cache.parents if (p / compiler).exists()), None)
            assert cc is not None, f"no {compiler} above {cache}"
        with cache_env(cache, cc):
            return codegen.compile_function(small_function())
    return load


def _case(name: str, build, error: type = CacheError, compiler: str | None = "cc-fail",
          names: str | None = None) -> Case:
    return Case(name, build, _load(compiler), error, None, names, ("cache",))


def _compiler_case(name: str, build, script: str) -> Case:
    """A case whose error comes from the compiler ``script``: the message names it."""
    return _case(name, build, CompileError, script, script)


# -- cache folders --------------------------------------------------------------------------------

def _mode_folder(mode: int):
    def build(folder: Path) -> Path:
        failing_compiler(folder)
        cache = folder / "cache"
        cache.mkdir()
        cache.chmod(mode)
        return cache
    return build


def _foreign_owned(folder: Path) -> Path:
    failing_compiler(folder)
    cache = folder / "cache"
    cache.mkdir(mode=0o700)
    os.chown(cache, 54321, 54321)
    return cache


def _file_as_folder(folder: Path) -> Path:
    failing_compiler(folder)
    cache = folder / "cache"
    cache.write_text("not a folder\n")
    return cache


def _under_a_file(folder: Path) -> Path:
    failing_compiler(folder)
    (folder / "plain").write_text("a file\n")
    return folder / "plain" / "cache"


def _symlink_to_world_writable(folder: Path) -> Path:
    failing_compiler(folder)
    shared = folder / "shared"
    shared.mkdir()
    shared.chmod(0o777)
    cache = folder / "cache"
    cache.symlink_to(shared)
    return cache


# -- compilers ---------------------------------------------------------------------------------

def _script(name: str, body: str):
    def build(folder: Path) -> Path:
        write_script(folder, name, body)
        return folder / "cache"
    return build


def _truncated_elf_compiler(folder: Path) -> Path:
    donor = _some_shared_object()
    head = folder / "head.bin"
    folder.mkdir(parents=True, exist_ok=True)
    head.write_bytes(donor.read_bytes()[:4096])
    write_script(folder, "cc-trunc", f"cat '{head}' > \"$out\"\nexit 0")
    return folder / "cache"


def _foreign_function_compiler(folder: Path) -> Path:
    """A compiler that builds a different Function under the expected symbol name."""
    other = codegen.generate_c(small_function(n=5), folder / "other")
    write_script(folder, "cc-other", f"exec '{real_compiler()}' -shared -fPIC '{other}' "
                                     "-o \"$out\" -lm")
    return folder / "cache"


def _executable_compiler(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    exe = compile_c("int main(void) { return 0; }\n", folder / "prog", "-no-pie")
    write_script(folder, "cc-exe", f"cp '{exe}' \"$out\"\nexit 0")
    return folder / "cache"


def _some_shared_object() -> Path:
    found = sorted(glob.glob(os.path.join(os.path.dirname(ca.__file__), "*.so*")),
                   key=os.path.getsize)
    return Path(found[-1] if found else "/nonexistent")


# -- libraries under the expected cache name ----------------------------------------------------

def _placed(kind: str):
    def build(folder: Path) -> Path:
        cc = failing_compiler(folder)
        cache = folder / "cache"
        cache.mkdir(mode=0o700)
        target = expected_library(cache, cc)
        sidecar = target.with_name(target.name + codegen.SIDECAR_SUFFIX)
        if kind in ("poison", "poison+sidecar"):
            poison_library(target, folder / "marker")
            if kind == "poison+sidecar":
                record = {"format": codegen.SIDECAR_FORMAT, "library": target.name,
                          "sha256": hashlib.sha256(target.read_bytes()).hexdigest(),
                          "size": target.stat().st_size, "key": "0" * 64,
                          "function": FUNCTION, "casadi": ca.__version__}
                sidecar.write_text(json.dumps(record))
            return cache
        donor = genuine_library(folder / "donor")
        donor_side = donor.with_name(donor.name + codegen.SIDECAR_SUFFIX)
        if kind in ("foreign", "relabelled"):  # another Function's genuine build
            donor = genuine_library(folder / "donor2", small_function(n=4))
            donor_side = donor.with_name(donor.name + codegen.SIDECAR_SUFFIX)
        if kind == "symlink":
            target.symlink_to(donor)
        elif kind == "folder":
            target.mkdir()
            (target / "x").write_text("x")
        else:
            shutil.copyfile(donor, target)
            target.chmod(0o700)
        if kind == "truncated":
            with open(target, "r+b") as fh:
                fh.truncate(target.stat().st_size // 2)
        if kind == "world-writable":
            target.chmod(0o666)
        if kind == "fifo-sidecar":
            os.mkfifo(sidecar)
        elif kind == "garbage-sidecar":
            sidecar.write_text("{ not json")
        elif kind == "foreign":
            shutil.copyfile(donor_side, sidecar)
        elif kind != "no-sidecar":  # the donor's sidecar as if written for this name
            record = json.loads(donor_side.read_text())
            record.update(library=target.name, key=codegen.cache_key(small_function(n=3),
                                                                     compiler=str(cc)))
            if kind == "wrong-sha":
                record["sha256"] = "0" * 64
            sidecar.write_text(json.dumps(record))
        return cache
    return build


def _lock_is_folder(folder: Path) -> Path:
    cc = failing_compiler(folder)
    cache = folder / "cache"
    cache.mkdir(mode=0o700)
    target = expected_library(cache, cc)
    (cache / f".{target.name}.lock").mkdir()
    return cache


def _library_name_taken_by_folder(folder: Path) -> Path:
    cache = folder / "cache"
    cache.mkdir(mode=0o700, parents=True)
    target = codegen.library_path(small_function(), directory=cache, compiler=real_compiler())
    target.mkdir()
    (target / "x").write_text("x")
    return cache


def cases() -> list[Case]:
    """The compile-cache cases (those needing a real C compiler only where one exists)."""
    has_cc = real_compiler() is not None
    out = [
        _case("cache folder world-writable", _mode_folder(0o777)),
        _case("cache folder world-writable with sticky bit", _mode_folder(0o1777)),
        _case("cache path is a regular file", _file_as_folder),
        _case("cache path below a regular file", _under_a_file, names="plain"),
        _case("cache folder symlink to a world-writable folder", _symlink_to_world_writable),
        _compiler_case("compiler exits 1", _script("cc-fail", "echo 'x.c: error: boom' >&2\n"
                                                              "exit 1"), "cc-fail"),
        _compiler_case("compiler killed by a signal", _script("cc-kill", "kill -9 $$"),
                       "cc-kill"),
        _compiler_case("compiler exits 0 writing garbage",
                       _script("cc-garbage", "echo 'not a library' > \"$out\"\nexit 0"),
                       "cc-garbage"),
        _compiler_case("compiler exits 0 writing nothing", _script("cc-empty", "exit 0"),
                       "cc-empty"),
        _compiler_case("compiler exits 0 removing its output",
                       _script("cc-rm", "rm -f \"$out\"\nexit 0"), "cc-rm"),
        _compiler_case("compiler exits 0 writing random bytes",
                       _script("cc-random", "head -c 20000 /dev/urandom > \"$out\"\nexit 0"),
                       "cc-random"),
        _compiler_case("compiler exits 0 writing an ELF header only",
                       _script("cc-elfhead", "printf '\\177ELF\\002\\001\\001' > \"$out\"\n"
                                             "exit 0"), "cc-elfhead"),
        _case("lock file name taken by a folder", _lock_is_folder),
    ]
    if _some_shared_object().exists():
        out.append(_compiler_case("compiler exits 0 writing a truncated shared object",
                                  _truncated_elf_compiler, "cc-trunc"))
    if hasattr(os, "getuid") and os.getuid() == 0:
        out.append(_case("cache folder owned by another user", _foreign_owned))
    if has_cc:
        out += [
            _compiler_case("compiler exits 0 building another Function",
                           _foreign_function_compiler, "cc-other"),
            _compiler_case("compiler exits 0 building an executable", _executable_compiler,
                           "cc-exe"),
            _case("poisoned library (constructor), no sidecar", _placed("poison")),
            _case("poisoned library with a forged sidecar", _placed("poison+sidecar")),
            _case("genuine library without sidecar", _placed("no-sidecar")),
            _case("truncated library with its sidecar", _placed("truncated")),
            _case("another Function's library and sidecar", _placed("foreign")),
            _case("another Function's library, sidecar relabelled for this name",
                  _placed("relabelled")),
            _case("library with a sidecar of the wrong SHA-256", _placed("wrong-sha")),
            _case("sidecar is a FIFO", _placed("fifo-sidecar")),
            _case("sidecar is not JSON", _placed("garbage-sidecar")),
            _case("library is a symlink", _placed("symlink")),
            _case("library writable by others", _placed("world-writable")),
            _case("library name taken by a folder (failing compiler)", _placed("folder")),
            _case("library name taken by a folder (real compiler)",
                  _library_name_taken_by_folder, compiler=None),
        ]
    return out
