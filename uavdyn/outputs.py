"""Nothing half-written: files and folders that commands produce are built under a temporary
sibling name and renamed into place only when complete, and a folder that is not a previous
output of the same command is never overwritten without ``force``.

An output folder carries a small marker (``.uavdyn-output.json``: command, files) so a later run
of the same command may replace it, and ``force`` into a foreign folder removes only the stale
files of that command, never the user's own. Either way the folder is swapped in whole: an
interrupt leaves the old folder or the new one, never a mix.

Single output files obey the same rule (:func:`check_output_files`): an existing non-empty file
is replaced only if uavdyn wrote it and it is unchanged since, or with ``force``. What uavdyn
wrote is recorded beside it, in its folder's ``.uavdyn-files.json`` (file name -> command and
SHA-256 of the content; :func:`record_outputs`), so the rule holds for every format (CSV, TOML,
JSON, ``.npz``, PNG) without touching the files themselves; a file edited since is the user's.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import threading
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

MARKER = ".uavdyn-output.json"
REGISTRY = ".uavdyn-files.json"   # single files uavdyn wrote in a folder (module docstring)
REGISTRY_MAX_BYTES = 4 * 2**20     # a larger record is not read (nothing counts as uavdyn's)


class OutputError(ValueError):
    """An output path cannot be written safely; the message names it and says why."""


def _temp_sibling(path: Path, kind: str) -> Path:
    return path.with_name(f".{path.name}.{kind}-{os.getpid()}-{threading.get_ident()}-"
                          f"{uuid.uuid4().hex[:8]}")


def _check_parent(path: Path, create_parents: bool) -> None:
    parent = path.parent
    if parent.exists():
        if not parent.is_dir():
            raise OutputError(f"{path}: its parent {parent} is not a folder")
        return
    if not create_parents:
        raise OutputError(f"{path}: folder {parent} does not exist (create it first)")
    check_output_file(path)
    parent.mkdir(parents=True, exist_ok=True)


def check_output_file(path: str | Path) -> None:
    """Check, before any work, that ``path`` could be written by :func:`atomic_file` (its
    folder exists, or may be created inside the current folder); creates nothing.

    Raises
    ------
    OutputError
        If it could not, naming the path and why.
    """
    path = Path(path)
    parent = path.parent
    if path.is_dir():
        raise OutputError(f"{path}: is a folder, not a file")
    if parent.exists():
        if not parent.is_dir():
            raise OutputError(f"{path}: its parent {parent} is not a folder")
        return
    cwd = Path.cwd().resolve()
    resolved = parent.resolve()
    if resolved != cwd and cwd not in resolved.parents:
        raise OutputError(f"{path}: will not create folder {parent} outside the current folder "
                          "(create it first)")


@contextmanager
def atomic_file(path: str | Path, create_parents: bool = True) -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` to write; rename it to ``path`` when the block
    ends without error, delete it otherwise. The old ``path`` stays intact until then.

    Raises
    ------
    OutputError
        If the parent folder is missing and may not be created (outside the current folder).
    """
    path = Path(path)
    _check_parent(path, create_parents)
    tmp = _temp_sibling(path, "tmp")
    try:
        yield tmp
        if not tmp.exists():
            raise OutputError(f"{path}: nothing was written")
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextmanager
def atomic_files(*paths: str | Path, create_parents: bool = True) -> Iterator[tuple[Path, ...]]:
    """Yield a temporary sibling of each of ``paths`` to write; when the block ends without
    error, put them in place as one output (e.g. weights and the history that belongs to
    them): each old file is renamed aside, each new one renamed in, then the old ones are
    deleted. An error or interrupt at any rename moves every new file out and every old file
    back, so ``paths`` hold the old set or the new set, never a mix (a hard kill in the
    microseconds between the renames may leave the old files beside under ``.<name>.old-*``).
    Temporary files are deleted when the block fails.

    Raises
    ------
    OutputError
        If two paths are one file, a path is a folder, a parent is missing and may not be
        created, or the block left a temporary file unwritten.
    """
    paths = tuple(Path(p) for p in paths)
    if len({p.resolve() for p in paths}) != len(paths):
        raise OutputError(f"{', '.join(map(str, paths))}: two outputs are the same file")
    for path in paths:
        if path.is_dir():
            raise OutputError(f"{path}: is a folder, not a file")
        _check_parent(path, create_parents)
    tmps = tuple(_temp_sibling(p, "tmp") for p in paths)
    try:
        yield tmps
        for path, tmp in zip(paths, tmps):
            if not tmp.exists():
                raise OutputError(f"{path}: nothing was written")
        _replace_together(tmps, paths)
    finally:
        for tmp in tmps:
            if tmp.exists():
                tmp.unlink()


def _replace_together(tmps: tuple[Path, ...], paths: tuple[Path, ...]) -> None:
    """Rename each ``tmps[i]`` to ``paths[i]``, all or none (see :func:`atomic_files`)."""
    moved: list[tuple[Path, Path]] = []   # (path, the old file's name aside)
    placed: list[tuple[Path, Path]] = []  # (new file's temporary name, path)
    try:
        for path in paths:
            if path.exists() or path.is_symlink():
                old = _temp_sibling(path, "old")
                moved.append((path, old))
                os.replace(path, old)
        for tmp, path in zip(tmps, paths):
            placed.append((tmp, path))
            os.replace(tmp, path)
    except BaseException:
        for tmp, path in reversed(placed):
            if not tmp.exists() and path.exists():  # the new file went in: take it out
                path.unlink()
        for path, old in reversed(moved):
            if old.exists() or old.is_symlink():
                os.replace(old, path)
        raise
    for _, old in moved:
        old.unlink(missing_ok=True)


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary sibling."""
    with atomic_file(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def _marker(folder: Path) -> dict | None:
    try:
        doc = json.loads((folder / MARKER).read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


def check_output_folder(path: str | Path, command: str, force: bool = False) -> None:
    """Refuse, before any work is done, a non-empty ``path`` that is not a previous output of
    ``command`` (unless ``force``), or a path that is a file.

    Raises
    ------
    OutputError
        Naming the folder and the way out (``--force`` or another folder).
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{path}: exists and is not a folder")
    if not path.exists() or not any(path.iterdir()) or force:
        return
    marker = _marker(path)
    if marker is None or marker.get("command") != command:
        what = f"output of 'uavdyn {marker['command']}'" if marker else "not a uavdyn output"
        raise OutputError(f"{path}: folder is not empty and is {what}; choose an empty or new "
                          f"folder, or give --force to replace this command's files in it")


@contextmanager
def output_folder(path: str | Path, command: str, force: bool = False,
                  create_parents: bool = True) -> Iterator[Path]:
    """Yield a temporary sibling folder to fill; when the block ends without error it replaces
    ``path`` whole (see the module docstring for what happens to an existing ``path``).

    Raises
    ------
    OutputError
        As :func:`check_output_folder`, or if the parent cannot be created.
    """
    path = Path(path)
    check_output_folder(path, command, force)
    _check_parent(path, create_parents)
    tmp = _temp_sibling(path, "partial")
    tmp.mkdir()
    try:
        yield tmp
        files = sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*") if p.is_file())
        (tmp / MARKER).write_text(json.dumps({"command": command, "files": files}, indent=1))
        _commit(tmp, path, command, files)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def _swap(tmp: Path, path: Path) -> None:
    """Put the complete folder ``tmp`` in place of ``path`` (two atomic renames; an interrupt
    between them puts the old folder back, so ``path`` is always one or the other)."""
    old = _temp_sibling(path, "old")
    os.replace(path, old)
    try:
        os.replace(tmp, path)
    except BaseException:
        if not path.exists():
            os.replace(old, path)
        raise
    shutil.rmtree(old, ignore_errors=True)


def _carry_over(path: Path, tmp: Path, skip: set[str]) -> None:
    """Link (or copy) every entry of ``path`` not named in ``skip`` into ``tmp``: the user's own
    files of a foreign folder survive the swap unchanged."""
    for src in sorted(path.rglob("*")):
        rel = str(src.relative_to(path))
        if rel in skip or src.is_dir() and not src.is_symlink():
            continue
        dst = tmp / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.is_symlink():
            os.symlink(os.readlink(src), dst)
            continue
        try:
            os.link(src, dst)
        except OSError:
            shutil.copy2(src, dst)


def _commit(tmp: Path, path: Path, command: str, files: list[str]) -> None:
    marker = _marker(path) if path.exists() else None
    own = marker is not None and marker.get("command") == command
    if own:  # only a folder holding nothing but that output may be swapped whole
        present = {str(p.relative_to(path)) for p in path.rglob("*") if p.is_file()}
        own = present <= set(marker.get("files", [])) | {MARKER}
    if not path.exists() or not any(path.iterdir()):
        if path.exists():
            path.rmdir()
        os.replace(tmp, path)
        return
    if not own:
        # --force into a foreign folder: the new folder gets the user's own files too (not
        # the stale files of an earlier run of this command), then is swapped in whole, so an
        # interrupt never leaves a mix of old and new outputs
        same = marker is not None and marker.get("command") == command
        stale = set(marker.get("files", [])) if same else set()
        _carry_over(path, tmp, set(files) | stale | {MARKER})
    _swap(tmp, path)


def _digest(path: Path) -> str:
    """SHA-256 of a file's content (read in blocks)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _registry(folder: Path) -> dict:
    """The record of single files uavdyn wrote in ``folder`` (empty if none or unreadable)."""
    path = folder / REGISTRY
    try:
        if path.is_symlink() or not path.is_file() or path.stat().st_size > REGISTRY_MAX_BYTES:
            return {}
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    files = doc.get("files") if isinstance(doc, dict) else None
    return files if isinstance(files, dict) else {}


def written_by_uavdyn(path: str | Path) -> bool:
    """Whether ``path`` is a file uavdyn wrote (:func:`record_outputs`), unchanged since."""
    path = Path(path)
    entry = _registry(path.parent).get(path.name)
    if not isinstance(entry, dict) or path.is_symlink() or not path.is_file():
        return False
    try:
        return entry.get("sha256") == _digest(path)
    except OSError:
        return False


def check_output_files(*paths: str | Path, force: bool = False, option: str = "--force"
                       ) -> None:
    """Refuse, before any work, to replace a non-empty file that uavdyn did not write (or that
    was changed since), unless ``force``, or a path that is a folder (its parent folder is
    :func:`check_output_file`'s matter).

    Parameters
    ----------
    *paths : str or Path
        The single files a command will write.
    force : bool
        The command's ``--force``: replace them whatever they are.
    option : str
        The option named in the message.

    Raises
    ------
    OutputError
        One line naming the file and ``option``.
    """
    for path in map(Path, paths):
        if path.is_dir():
            raise OutputError(f"{path}: is a folder, not a file")
        if force or not (path.exists() or path.is_symlink()):
            continue
        if path.is_symlink() or (path.stat().st_size > 0 and not written_by_uavdyn(path)):
            raise OutputError(f"{path}: exists and was not written by uavdyn (or was changed "
                              f"since); choose another file or give {option} to overwrite it")


def record_outputs(*paths: str | Path, command: str) -> None:
    """Record that ``command`` wrote ``paths`` (each folder's :data:`REGISTRY`, replaced
    atomically), so a later run may replace them (:func:`check_output_files`). Paths that do
    not exist are skipped; entries of files gone from the folder are dropped."""
    by_folder: dict[Path, list[Path]] = {}
    for path in map(Path, paths):
        if path.is_file() and not path.is_symlink():
            by_folder.setdefault(path.parent, []).append(path)
    for folder, written in by_folder.items():
        files = {name: entry for name, entry in _registry(folder).items()
                 if (folder / name).is_file()}
        for path in written:
            files[path.name] = {"command": command, "sha256": _digest(path)}
        write_text_atomic(folder / REGISTRY, json.dumps({"files": files}, indent=1,
                                                        sort_keys=True) + "\n")


@contextmanager
def single_outputs(*paths: str | Path, command: str, force: bool = False) -> Iterator[None]:
    """Check ``paths`` (:func:`check_output_files`) on entry and record them as ``command``'s
    (:func:`record_outputs`) when the block, which writes them, ends without error."""
    check_output_files(*paths, force=force)
    yield
    record_outputs(*paths, command=command)
