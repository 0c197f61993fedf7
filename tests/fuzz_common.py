"""Shared shape of the malformed-input (fuzz) cases of the five loaders, run by
``tests/test_fuzz.py``: each case builds one malformed input in its own folder and says how the
API and the CLI are called on it and which error type the API must raise."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class Case:
    """One malformed input.

    Attributes
    ----------
    name : str
        Short description (test id).
    build : callable
        ``build(folder) -> path``: writes the malformed input inside ``folder`` (which also
        holds nothing else of interest) and returns the path the loader is given.
    load : callable
        ``load(path)``: the API call that must raise ``error``.
    error : type
        The loader's own error type.
    cli : callable or None
        ``cli(path, out_folder) -> argv`` for ``uavdyn.cli.main``; None if there is no CLI
        route for this loader input.
    names : str or None
        A substring the message must contain (default: the file name of ``path``).
    """

    name: str
    build: Callable[[Path], Path]
    load: Callable[[Path], object]
    error: type
    cli: Callable[[Path, Path], list[str]] | None = None
    names: str | None = None
    tags: tuple[str, ...] = field(default_factory=tuple)
