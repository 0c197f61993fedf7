"""Ctrl-C through CasADi: a KeyboardInterrupt, never a failed solve the program carries on from.

CasADi polls Python's signals and consumes Ctrl-C. Its solvers throw their own C++ exception:
most calls then raise ``RuntimeError`` ending in ``KeyboardInterrupt``, while Ipopt only ends
the solve (status ``NonIpopt_Exception_Thrown``). Its conversion of NumPy arguments runs a
Python helper and discards any exception raised there (or garbles it into a ``SystemError``).
These helpers give the interrupt back: recognised in error paths, recorded while a command runs
and raised again at the next step of a long loop.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Iterator

from tqdm import tqdm

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


_pressed = False  # Ctrl-C arrived while ctrl_c_remembered() was active, not yet raised again


def _remember_and_raise(signum, frame) -> None:
    global _pressed
    _pressed = True
    raise KeyboardInterrupt


@contextlib.contextmanager
def ctrl_c_remembered() -> Iterator[None]:
    """Remember every Ctrl-C during the block, so that :func:`check_interrupted` can raise one
    that a library swallowed (CasADi's conversion of NumPy arguments calls Python helpers and
    discards any exception raised in them, a KeyboardInterrupt included).

    Only in the main thread and over Python's default handler (a program's own handler, or
    SIGINT ignored, is left alone); nested uses share the outermost one's record.
    """
    global _pressed
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield
        return
    _pressed = False
    previous = signal.signal(signal.SIGINT, _remember_and_raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        _pressed = False


def ctrl_c_pending() -> bool:
    """Whether Ctrl-C arrived under :func:`ctrl_c_remembered` and was not raised again since
    (an error raised meanwhile may be its garbled form: CasADi's NumPy conversion turns it
    into a ``SystemError`` or ``TypeError``)."""
    return _pressed


def stands_for_interrupt(exc: BaseException) -> bool:
    """Whether ``exc`` is CasADi's rendering of Ctrl-C or was raised while one is pending."""
    return is_casadi_interrupt(exc) or ctrl_c_pending()


def check_interrupted() -> None:
    """Raise ``KeyboardInterrupt`` if Ctrl-C was pressed (under :func:`ctrl_c_remembered`)
    and has not been raised since: called once per iteration of long loops (epochs, sorties,
    solver iterations, control steps), it bounds how long a swallowed Ctrl-C goes unheeded."""
    global _pressed
    if _pressed:
        _pressed = False
        raise KeyboardInterrupt


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """Run a CasADi solve so that Ctrl-C during it raises ``KeyboardInterrupt`` when it returns,
    even where the solver swallowed it (Ipopt).

    An error raised while a Ctrl-C is pending becomes the ``KeyboardInterrupt`` too. Costs two
    ``sigaction`` calls (tens of microseconds) unless :func:`ctrl_c_remembered` is
    already active (the command line): for solves of milliseconds, not for a real-time loop's
    inner call (there, :func:`reraise_interrupt` in the error path).
    """
    with ctrl_c_remembered():
        try:
            yield
        except Exception as exc:
            if stands_for_interrupt(exc):
                raise KeyboardInterrupt from None
            raise
        check_interrupted()


LOG_INTERVAL_S = 30.0  # a bar written to a file or pipe (a log) redraws at most this often


class CheckedBar(tqdm):
    """A tqdm progress bar that calls :func:`check_interrupted` at every step (iteration or
    ``update``), shown or not: every long loop of the package advances one. Written to a
    file or pipe rather than a terminal it redraws every :data:`LOG_INTERVAL_S` at most, so
    a log gets a progress line every half minute, not ten a second."""

    def __init__(self, *args, **kwargs) -> None:
        stream = kwargs.get("file") or sys.stderr
        is_terminal = getattr(stream, "isatty", lambda: False)
        if "mininterval" not in kwargs and not is_terminal():
            kwargs["mininterval"] = LOG_INTERVAL_S
        super().__init__(*args, **kwargs)

    def update(self, n: float | None = 1) -> bool | None:
        check_interrupted()
        return super().update(n)

    def __iter__(self):
        for item in super().__iter__():
            check_interrupted()
            yield item
