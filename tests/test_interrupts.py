"""Ctrl-C through CasADi (``uavdyn.interrupts``) and while the command line loads.

CasADi's solvers poll Python's signals and consume Ctrl-C: a Newton solve raises a
``RuntimeError`` ending in ``KeyboardInterrupt``, an Ipopt solve just ends as failed; its
conversion of NumPy arguments discards a KeyboardInterrupt raised in its Python helpers. These
tests press Ctrl-C on child processes in the middle of such work; the first checks that CasADi
still behaves as the module says (the reason it exists)."""

import signal
import time

import pytest
from interrupting import interrupt_when, python_child

from uavdyn.cli import main
from uavdyn.interrupts import ctrl_c_pending, interruptible, is_casadi_interrupt

LONG_IPOPT_SOLVES = """
import time
import casadi as ca
x = ca.SX.sym("x", 400)
f = ca.sum1(100 * (x[1:] - x[:-1] ** 2) ** 2 + (1 - x[:-1]) ** 2)
solver = ca.nlpsol("s", "ipopt", {"x": x, "f": f}, {
    "print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes"})

def solve_for(seconds):
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        solver(x0=-1.2)
        status = solver.stats()["return_status"]
        if status != "Solve_Succeeded":
            print("solve ended:", status)
            break

print("ready", flush=True)
try:
"""

CAUGHT = """except KeyboardInterrupt:
    print("KeyboardInterrupt")
"""

NEWTON_SOLVES = """
import casadi as ca
z = ca.SX.sym("z", 60)
g = ca.Function("g", [z], [3 * ca.sin(z) + z ** 3 - 1])
newton = ca.rootfinder("newton", "newton", g, {"abstol": 1e-14, "error_on_fail": False})
print("ready", flush=True)
"""


def _interrupted_after_ready(code: str) -> tuple[str, str]:
    """Run ``code`` in a child, press Ctrl-C 0.3 s after it printed ``ready``."""
    proc = python_child(code)
    assert proc.stdout.readline().strip() == "ready", proc.communicate()[1][-2000:]
    ready_at = time.monotonic()
    return interrupt_when(proc, lambda _: time.monotonic() - ready_at > 0.3, exit_within=25.0)


def test_ipopt_swallows_ctrl_c_and_interruptible_gives_it_back():
    out, _ = _interrupted_after_ready(LONG_IPOPT_SOLVES + "    solve_for(20.0)\n" + CAUGHT)
    assert out.strip() == "solve ended: NonIpopt_Exception_Thrown"  # and the program went on
    out, _ = _interrupted_after_ready(LONG_IPOPT_SOLVES + """
    from uavdyn.interrupts import interruptible
    with interruptible():
        solve_for(20.0)
""" + CAUGHT)
    assert out.strip().splitlines()[-1] == "KeyboardInterrupt", out  # after the solve ended


def test_a_newton_solve_interrupted_raises_what_is_casadi_interrupt_recognises():
    out, _ = _interrupted_after_ready(NEWTON_SOLVES + """
import time
from uavdyn.interrupts import ctrl_c_pending, interruptible, is_casadi_interrupt
t0 = time.monotonic()
try:
    while time.monotonic() - t0 < 20:
        newton(ca.DM.ones(60) * 0.3)
    print("never interrupted")
except RuntimeError as exc:
    print("recognised" if is_casadi_interrupt(exc) else f"not recognised: {exc}")
except KeyboardInterrupt:
    print("between solves")
""")
    # Ctrl-C lands inside a solve (nearly all of the loop's time) or, rarely, between two
    assert out.strip() in ("recognised", "between solves"), out


def test_is_casadi_interrupt_only_on_its_message():
    casadi_message = ("Error in Function::call for 'newton' [Newton] at "
                      ".../casadi/core/function.cpp:514:\nKeyboardInterrupt")
    assert is_casadi_interrupt(RuntimeError(casadi_message))
    assert not is_casadi_interrupt(RuntimeError("Error in Function::call: singular Jacobian"))
    assert not is_casadi_interrupt(ValueError("KeyboardInterrupt"))
    assert not is_casadi_interrupt(RuntimeError("KeyboardInterrupt in the middle\nof a line"))


def test_interruptible_converts_and_restores_the_handler():
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt), interruptible():
        raise RuntimeError("Error in Function::call for 's' [Newton]\nKeyboardInterrupt")
    with pytest.raises(RuntimeError, match="singular"), interruptible():
        raise RuntimeError("singular")
    assert signal.getsignal(signal.SIGINT) is before


def test_command_line_interrupted_inside_a_casadi_solver(monkeypatch, capsys):
    """A CasADi interrupt that reaches the command line is Ctrl-C (exit 130, one line), not
    an internal error."""
    import uavdyn.cli.model_commands as commands

    def interrupted(args):
        raise RuntimeError("Error in Function::call for 'trim_solver' [Newton]\nKeyboardInterrupt")

    monkeypatch.setattr(commands, "cmd_trim", interrupted)
    assert main(["trim", "--airframe", "aerosonde"]) == 130
    assert capsys.readouterr().err.strip() == "uavdyn trim: interrupted"


def test_command_line_interrupted_while_loading():
    """Ctrl-C while the commands' modules load (made certain by an import hook that raises
    it there): one line and exit 130, no traceback."""
    code = """
import sys
class CtrlC:
    def find_spec(self, name, path=None, target=None):
        if name == "uavdyn.cli.app":
            raise KeyboardInterrupt
sys.meta_path.insert(0, CtrlC())
from uavdyn.cli import main
raise SystemExit(main(["trim", "--airframe", "aerosonde"]))
"""
    proc = python_child(code)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and err.strip() == "uavdyn: interrupted", err
    assert not out


SWALLOWING_LOOP = """
import time
from uavdyn.interrupts import CheckedBar, ctrl_c_remembered

READY = []

def library_that_swallows_everything():
    try:  # the whole call (its loop's own checks for signals included)
        if not READY:  # ready once the loop runs: on a loaded machine the start can take
            print("ready", flush=True)  # longer than the 0.3 s before the Ctrl-C
            READY.append(True)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 0.05:
            sum(range(1000))
    except BaseException:
        pass

def loop():
    for step in CheckedBar(range(400), disable=True):
        library_that_swallows_everything()
    print("never interrupted")

try:
    %s
except KeyboardInterrupt:
    print("KeyboardInterrupt")
"""


def test_a_swallowed_ctrl_c_is_raised_at_the_next_step_of_a_checked_loop():
    out, _ = _interrupted_after_ready(SWALLOWING_LOOP % "loop()")
    assert out.strip() == "never interrupted"  # what happens without the record (20 s)
    out, _ = _interrupted_after_ready(SWALLOWING_LOOP % "with ctrl_c_remembered(): loop()")
    assert out.strip() == "KeyboardInterrupt"


def test_command_line_error_after_a_swallowed_ctrl_c_is_the_interrupt(monkeypatch, capsys):
    """CasADi's NumPy conversion can turn Ctrl-C into a SystemError: with the Ctrl-C on record,
    the command line reports it as the interrupt, not as an internal error."""
    import uavdyn.cli.model_commands as commands

    def garbled(args):
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt:
            raise SystemError("DM.__array__ returned a result with an exception set") from None

    monkeypatch.setattr(commands, "cmd_trim", garbled)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        assert main(["trim", "--airframe", "aerosonde"]) == 130
    finally:
        signal.signal(signal.SIGINT, previous)
    assert capsys.readouterr().err.strip() == "uavdyn trim: interrupted"
    assert not ctrl_c_pending()  # the record ends with the command


def test_a_bar_written_to_a_log_redraws_every_half_minute_at_most():
    """Written to a file or pipe, a bar redraws at most every LOG_INTERVAL_S (a log holds the
    start and end lines, not ten a second); on a terminal tqdm's own interval stays."""
    import io

    from uavdyn.interrupts import LOG_INTERVAL_S, CheckedBar

    log = io.StringIO()
    with CheckedBar(total=300, file=log, desc="train") as bar:
        assert bar.mininterval == LOG_INTERVAL_S
        for _ in range(300):
            bar.update(1)
    lines = [part for part in log.getvalue().split("\r") if part.strip()]
    assert len(lines) <= 3 and "300/300" in lines[-1]

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    with CheckedBar(total=1, file=Terminal()) as bar:
        assert bar.mininterval < 1.0
    with CheckedBar(total=1, file=io.StringIO(), mininterval=0.5) as bar:
        assert bar.mininterval == 0.5
