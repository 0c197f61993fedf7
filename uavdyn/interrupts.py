"""Ctrl-C through CasADi: a KeyboardInterrupt, never a failed solve the program carries on from.

CasADi's solvers poll Python's signals while they iterate. On Ctrl-C they consume it and throw
their own C++ exception: most calls then raise ``RuntimeError`` ending in ``KeyboardInterrupt``;
inside Ipopt it only ends the solve (status ``NonIpopt_Exception_Thrown``) and Python never sees
the interrupt. These helpers give it back.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

CASADI_INTERRUPT = "KeyboardInterrupt"


def is_casadi_interrupt(exc: BaseException) -> bool:
    """Whether ``exc`` is CasADi's rendering of Ctrl-C (a ``RuntimeError`` whose last line is
    ``KeyboardInterrupt``)."""
    if not isinstance(exc, RuntimeError):
        return False
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return bool(lines) and lines[-1] == CASADI_INTERRUPT


def reraise_interrupt(exc: BaseException) -> None:
    """Raise ``KeyboardInterrupt`` if ``exc`` is CasADi's rendering of one (call it first in an
    ``except RuntimeError`` that treats the error as a failed solve)."""
    if is_casadi_interrupt(exc):
        raise KeyboardInterrupt from None


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """Run a CasADi solve so that Ctrl-C during it raises ``KeyboardInterrupt`` when it returns,
    even where the solver swallowed it (Ipopt).

    Costs two ``sigaction`` calls (tens of microseconds): for solves of milliseconds, not for a
    real-time loop's inner call (there, :func:`reraise_interrupt` in the error path). Outside
    the main thread, or where the program installed its own SIGINT handler, it only converts
    CasADi's ``RuntimeError``.
    """
    caught: list[int] = []
    previous = None
    if (threading.current_thread() is threading.main_thread()
            and signal.getsignal(signal.SIGINT) is signal.default_int_handler):
        def note_and_raise(signum, frame) -> None:
            caught.append(signum)
            signal.default_int_handler(signum, frame)
        previous = signal.signal(signal.SIGINT, note_and_raise)
    try:
        yield
    except RuntimeError as exc:
        reraise_interrupt(exc)
        raise
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt
