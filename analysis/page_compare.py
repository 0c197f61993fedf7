"""Compare a regenerated documentation page with the committed one, as the tutorials' ``--check``
does: numbers by tolerance (floating-point output differs in the last digits between CPUs),
timings and the machine ignored, everything else exactly."""

from __future__ import annotations

import math
import re

NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
# run-dependent text: wall times ("in 2.3 s", "wall time 25 s", "9.7s/epoch", "[00:11<00:45"),
# the machine and Python version of the page's own header
VOLATILE = re.compile(r"(?:\bin |wall time |took )\d+(?:\.\d+)? ?(?:s|ms|min)\b"
                      r"|\d+(?:\.\d+)?s/(?:epoch|it)"
                      r"|\[\d\d:\d\d[<,][^\]]*\]|Python \d+\.\d+\.\d+|\b(?:x86_64|aarch64|arm64)\b"
                      r"|\d+(?:\.\d+)? ?(?:ms|us) median|load (?:average )?[\d.]+")


def _numbers_agree(a: str, b: str, rel: float, absolute: float) -> bool:
    x, y = float(a), float(b)
    return math.isclose(x, y, rel_tol=rel, abs_tol=absolute) or (
        math.isnan(x) and math.isnan(y))


def line_difference(expected: str, actual: str, rel: float = 1e-6,
                    absolute: float = 1e-9) -> str | None:
    """What differs between two lines (None if nothing): their run-dependent parts
    (:data:`VOLATILE`) removed, their text compared exactly and their numbers to
    ``rel``/``absolute``."""
    a, b = VOLATILE.sub("<t>", expected), VOLATILE.sub("<t>", actual)
    if NUMBER.sub("#", a) != NUMBER.sub("#", b):
        return "the text differs"
    for x, y in zip(NUMBER.findall(a), NUMBER.findall(b)):
        if not _numbers_agree(x, y, rel, absolute):
            return f"the number {y} should be {x}"
    return None


def first_difference(expected: str, actual: str, rel: float = 1e-6,
                     absolute: float = 1e-9) -> str | None:
    """The first line where ``actual`` differs from ``expected`` (with both lines), or None
    (:func:`line_difference` on each line)."""
    old, new = expected.splitlines(), actual.splitlines()
    for n in range(max(len(old), len(new))):
        a = old[n] if n < len(old) else "<no line>"
        b = new[n] if n < len(new) else "<no line>"
        what = line_difference(a, b, rel, absolute)
        if what:
            return f"line {n + 1}: {what}\n  committed: {a}\n  this run:  {b}"
    return None
