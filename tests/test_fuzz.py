"""Malformed inputs to the five loaders (dataset, PX4 ULog/ALFA, weights, airframe, compile
cache), seeded, from the ``fuzz_*.py`` case modules: each must raise the loader's own error type
in one line naming the file, read no file outside its own folder (an audit hook records every
``open``), and on the CLI route exit with code 2, exactly one line on stderr, no traceback."""

from __future__ import annotations

import sys
from pathlib import Path

import fuzz_airframe
import fuzz_cache
import fuzz_dataset
import fuzz_ulog
import fuzz_weights
import pytest

from uavdyn.cli import main

MODULES = {"dataset": fuzz_dataset, "ulog": fuzz_ulog, "weights": fuzz_weights,
           "airframe": fuzz_airframe, "cache": fuzz_cache}
CASES = [(loader, case) for loader, module in MODULES.items() for case in module.cases()]
OPENED: list[str] | None = None


def _audit(event: str, args: tuple) -> None:
    if event == "open" and OPENED is not None and isinstance(args[0], (str, bytes, Path)):
        path = args[0].decode() if isinstance(args[0], bytes) else str(args[0])
        OPENED.append(path)


sys.addaudithook(_audit)


def test_enough_cases_per_loader():
    counts = {loader: sum(1 for ld, _ in CASES if ld == loader) for loader in MODULES}
    print(f"\nfuzz cases per loader: {counts}, total {len(CASES)}")
    assert len(CASES) >= 150 and all(n >= 10 for n in counts.values()), counts


def _outside(path: str, folder: Path, root: Path) -> bool:
    """An opened path that is in the test's root but not in the case folder, or a device."""
    p = Path(path)
    if not p.is_absolute():
        p = Path.cwd() / p
    resolved = p.resolve()
    if str(resolved).startswith("/dev/") and str(resolved) not in ("/dev/null", "/dev/urandom"):
        return True
    inside_root = root.resolve() in resolved.parents
    inside_folder = folder.resolve() in resolved.parents or resolved == folder.resolve()
    return inside_root and not inside_folder


@pytest.mark.parametrize("loader, case", CASES, ids=[f"{ld}:{c.name}" for ld, c in CASES])
def test_malformed_input_gives_one_clear_error(loader, case, tmp_path, capsys):
    global OPENED
    root = tmp_path
    folder = root / "case"
    folder.mkdir()
    path = case.build(folder)
    named = case.names or Path(path).name
    OPENED = []
    try:
        with pytest.raises(Exception) as info:
            case.load(path)
    finally:
        opened, OPENED = OPENED, None
    assert isinstance(info.value, case.error), \
        f"{type(info.value).__name__} instead of {case.error.__name__}: {info.value}"
    message = str(info.value)
    assert "\n" not in message.strip(), f"more than one line: {message!r}"
    assert named in message, f"message does not name {named}: {message}"
    bad = [p for p in opened if _outside(p, folder, root)]
    assert not bad, f"opened outside the case folder: {bad}"
    if case.cli is None:
        return
    capsys.readouterr()
    OPENED = []
    try:
        code = main(case.cli(path, root / "out"))
    finally:
        opened, OPENED = OPENED, None
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, f"exit {code}: {err}"
    assert len(lines) == 1 and "Traceback" not in err, err
    bad = [p for p in opened if _outside(p, folder, root)
           and (root / "out").resolve() not in Path(p).resolve().parents]
    assert not bad, f"the CLI opened outside the case folder: {bad}"
