"""Pressing Ctrl-C on a child Python process, as at a terminal, and collecting what it said."""

from __future__ import annotations

import codecs
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable


def python_child(code: str) -> subprocess.Popen:
    """``python -c code`` with Ctrl-C delivered as at a terminal even when the tests themselves
    run as a background job (a non-interactive shell starts those with SIGINT ignored, the
    child would inherit that, and Python would then install no KeyboardInterrupt handler)."""
    return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def uavdyn_child(args: list[str]) -> subprocess.Popen:
    """The ``uavdyn`` command line with ``args`` in a child process (see :func:`python_child`)."""
    return python_child(f"from uavdyn.cli import main; raise SystemExit(main({args!r}))")


def interrupt_when(proc: subprocess.Popen, ready: Callable[[str], bool], timeout: float = 120.0,
                   exit_within: float = 60.0) -> tuple[str, str]:
    """Send SIGINT once ``ready(stderr so far)`` holds and return the child's (stdout, stderr)
    after it exits. Both pipes are drained all along (a child blocked on a full pipe could
    neither get ready nor exit). A child that finished first, never got ready, or outlived
    ``exit_within`` seconds after the signal fails the test with the end of its stderr."""
    chunks: dict[str, list[str]] = {"out": [], "err": []}
    readers = [threading.Thread(target=_drain, args=(stream, chunks[key]), daemon=True)
               for key, stream in (("out", proc.stdout), ("err", proc.stderr))]
    for reader in readers:
        reader.start()

    def said() -> tuple[str, str]:
        return "".join(chunks["out"]), "".join(chunks["err"])

    def fail(why: str) -> AssertionError:
        proc.kill()
        proc.wait()
        for reader in readers:
            reader.join(5.0)
        return AssertionError(f"{why}; its stderr ends: {said()[1][-2000:]}")

    t0 = time.monotonic()
    while not ready(said()[1]):
        if proc.poll() is not None:
            raise fail("finished before it could be interrupted")
        if time.monotonic() - t0 > timeout:
            raise fail("never reached the point of interruption")
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=exit_within)
    except subprocess.TimeoutExpired:
        raise fail(f"still running {exit_within:g} s after Ctrl-C") from None
    for reader in readers:
        reader.join(10.0)
    return said()


def _drain(stream, into: list[str]) -> None:
    """Whatever arrives, as it arrives (a progress bar rewrites one line with carriage
    returns: waiting for whole lines would see nothing until the end)."""
    decoder = codecs.getincrementaldecoder("utf-8")(errors="replace")
    while data := os.read(stream.fileno(), 65536):
        into.append(decoder.decode(data))
    into.append(decoder.decode(b"", final=True))
