"""C source of a CasADi Function, and the compiled Functions it would call from outside."""

from __future__ import annotations

import os
import re
from pathlib import Path

import casadi as ca


def generate_c(func: ca.Function, directory: Path, name: str | None = None,
               with_header: bool = False, casadi_real: str = "double",
               with_jacobians: bool = False, others: tuple[ca.Function, ...] = ()) -> Path:
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
    others : tuple of casadi.Function
        More Functions generated into the same file (one bundle, one set of helpers).

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
    for other in others:
        gen.add(other)
    directory.mkdir(parents=True, exist_ok=True)
    gen.generate(str(directory) + os.sep)
    return directory / f"{name}.c"


_DECLARED = re.compile(r"^void (\w+)_incref\(void\);$", re.MULTILINE)


def _external_calls(source: str) -> list[str]:
    """Functions the generated source declares but does not define (compiled ``External``
    Functions called from the graph)."""
    return sorted(n for n in set(_DECLARED.findall(source))
                  if f"void {n}_incref(void) {{" not in source)
