"""Explicit Runge-Kutta steps from a Butcher tableau, written once against an ``ops`` namespace
so the same stages build the CasADi step, the NumPy baseline and the torch training step."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from fractions import Fraction


@dataclass(frozen=True)
class ButcherTableau:
    """Coefficients of an explicit RK method: ``a`` strictly lower-triangular, weights ``b``,
    nodes ``c``; the constructor checks shapes and the consistency conditions
    ``sum(b) = 1`` and ``c_i = sum_j a_ij``.

    Parameters
    ----------
    name : str
        Short name (``"rk4"``).
    order : int
        Classical order of accuracy, as documented.
    a, b, c : sequences of numbers
        The tableau.

    Raises
    ------
    ValueError
        If the tableau is not explicit or not consistent.
    """

    name: str
    order: int
    a: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    c: tuple[float, ...]

    def __post_init__(self) -> None:
        s = len(self.b)
        if len(self.c) != s or len(self.a) != s or any(len(row) != s for row in self.a):
            raise ValueError(f"tableau '{self.name}': a must be {s}x{s} and c of length {s}")
        for i, row in enumerate(self.a):
            if any(row[j] != 0 for j in range(i, s)):
                raise ValueError(f"tableau '{self.name}': a[{i}] has entries on or above the "
                                 "diagonal (not explicit)")
            if abs(sum(row) - self.c[i]) > 1e-14:
                raise ValueError(f"tableau '{self.name}': c[{i}] = {self.c[i]} differs from the "
                                 f"row sum of a[{i}] = {sum(row)}")
        if abs(sum(self.b) - 1) > 1e-14:
            raise ValueError(f"tableau '{self.name}': weights b sum to {sum(self.b)}, not 1")

    @property
    def stages(self) -> int:
        return len(self.b)


def _tableau(name: str, order: int, a, b, c) -> ButcherTableau:
    def f(v):
        return float(Fraction(v))

    return ButcherTableau(name, order, tuple(tuple(f(v) for v in row) for row in a),
                          tuple(f(v) for v in b), tuple(f(v) for v in c))


RK4 = _tableau("rk4", 4,
               [[0, 0, 0, 0], ["1/2", 0, 0, 0], [0, "1/2", 0, 0], [0, 0, 1, 0]],
               ["1/6", "1/3", "1/3", "1/6"], [0, "1/2", "1/2", 1])
EULER = _tableau("euler", 1, [[0]], [1], [0])
HEUN = _tableau("heun", 2, [[0, 0], [1, 0]], ["1/2", "1/2"], [0, 1])


def explicit_rk_step(tableau: ButcherTableau, rhs: Callable, x, dt):
    """One step ``x -> x + dt * sum_i b_i k_i`` of the autonomous ``rhs(x)`` (controls and
    parameters held over the step are closed over by ``rhs``). Works for any array type whose
    ``+`` and ``*`` by scalars mean what they do for CasADi, NumPy and torch."""
    k: list = []
    for i in range(tableau.stages):
        xi = x
        for j, aij in enumerate(tableau.a[i][:i]):
            if aij != 0:
                xi = xi + dt * aij * k[j]
        k.append(rhs(xi))
    incr = None
    for bi, ki in zip(tableau.b, k):
        if bi != 0:
            incr = bi * ki if incr is None else incr + bi * ki
    return x + dt * incr


def available_tableaux() -> Sequence[str]:
    return tuple(t.name for t in (EULER, HEUN, RK4))
