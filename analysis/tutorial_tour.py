"""Build the five-minute tour: run its commands, write the page and the README's tour block.

Runs the tour's ``uavdyn`` commands in this process (``uavdyn.cli.app.main``) inside a
temporary folder, on small emulated data, and writes what each printed into
``docs/tutorials/tour.md`` and into ``README.md`` between ``<!-- tour:start -->`` and
``<!-- tour:end -->``. Long outputs are trimmed, with a visible ``...`` line. So the printed
output shown to users is always what the commands print::

    python analysis/tutorial_tour.py            # run the tour, rewrite both files
    python analysis/tutorial_tour.py --check    # run it, compare; exit 1 naming the first
                                                # command whose shown output differs

``--check`` compares numbers by tolerance (relative 1e-6 or absolute 1e-9: floating-point
output differs in its last digits between CPUs) and ignores timing figures ("in 2.3 s").
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from page_compare import line_difference  # the script's own folder is on the import path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGE = ROOT / "docs" / "tutorials" / "tour.md"
START, END = "<!-- tour:start -->", "<!-- tour:end -->"
REL_TOL, ABS_TOL = 1e-6, 1e-9


Keep = tuple[int, int] | Callable[[str], bool] | None


@dataclass(frozen=True)
class Step:
    """One command of the tour: what it says, and how much of its output each file shows
    (``None``: all of it; ``(head, tail)``: the first and last lines; a function: the lines it
    keeps). Whatever is cut is one ``...`` line per cut."""

    argv: tuple[str, ...]
    note: str
    page: Keep = None
    readme: Keep = None
    in_readme: bool = True


def _not_a_failed_trim(line: str) -> bool:
    return "not trimmed" not in line


def _identify_summary(line: str) -> bool:
    return not line.startswith("  ") or " = " in line or "determined" in line or \
        "validation" in line


def _one_second(line: str) -> bool:
    return ", 1 s (" in line or line.startswith("wrote")


STEPS = (
    Step(("airframes",), "The shipped presets:"),
    Step(("trim", "--airframe", "aerosonde"),
         "Trim the fixed wing at its nominal 25 m/s (JSON):", in_readme=False),
    Step(("modes", "--airframe", "aerosonde"),
         "Trim, linearise and list the modes:"),
    Step(("simulate", "--airframe", "aerosonde", "--input", "doublet", "--duration", "10",
          "--out", "doublet.csv"),
         "Fly a 2 deg elevator doublet from trim with the compiled RK4 (an interchange CSV):"),
    Step(("generate-data", "--airframe", "aerosonde", "--sorties", "16", "--duration", "20",
          "--missions", "sysid_3211,aggressive", "--out", "flights", "--no-progress"),
         "Emulate 16 short sorties (half of them in turbulence) as a flight-data set. The "
         "emulator is richer than the model: actuator lags, alpha-dot terms, dynamic stall, "
         "gusts, sensor noise."),
    Step(("split", "flights", "--seed", "2"),
         "Assign whole sorties to train, validation and test:"),
    Step(("identify", "--airframe", "aerosonde", "--dataset", "flights", "--params",
          "C_m_alpha,C_m_q,C_m_delta_e,tau_elevator", "--out", "aerosonde_fit.toml", "--quiet"),
         "Fit four physical parameters to the train sorties by output error. Each comes with a "
         "standard error corrected for correlated residuals; what the data cannot determine is "
         "flagged.",
         readme=_identify_summary),
    Step(("evaluate", "--airframe", "aerosonde", "--identified", "aerosonde_fit.toml",
          "--dataset", "flights", "--out", "evaluation.json"),
         "Score nominal against identified physics on the held-out test sorties: pitch RMSE, "
         "pooled, with a bootstrap interval over sorties where a group has two or more (one "
         "sortie per group here, so none: emulate more sorties for one).",
         readme=_one_second),
    Step(("modes", "--airframe", "aerosonde", "--hybrid"),
         "The shipped learned correction on the shipped identified Aerosonde: its discrete map "
         "beside the physics, and the stability rule at every trim of its training envelope "
         "(the trims outside the airframe's envelope are cut here):",
         page=_not_a_failed_trim, in_readme=False),
)


def run(argv: tuple[str, ...]) -> tuple[int, str]:
    """One ``uavdyn`` command in this process: its exit code and everything it printed."""
    from uavdyn.cli.app import main

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer), contextlib.redirect_stderr(buffer):
        code = main(list(argv))
    return code, buffer.getvalue()


def trimmed(text: str, keep: Keep) -> str:
    """The output with what ``keep`` leaves out replaced by one ``...`` line per cut."""
    lines = text.strip("\n").splitlines()
    if keep is None:
        return "\n".join(lines)
    if callable(keep):
        kept = [keep(line) for line in lines]
    else:
        head, tail = keep
        if len(lines) <= head + tail + 1:
            return "\n".join(lines)
        kept = [i < head or i >= len(lines) - tail for i in range(len(lines))]
    shown: list[str] = []
    for line, keep_it in zip(lines, kept):
        if keep_it:
            shown.append(line)
        elif not shown or shown[-1] != "...":
            shown.append("...")
    return "\n".join(shown)


def run_tour() -> tuple[list[tuple[Step, str]], float]:
    """Every step's printed output (run in a temporary folder) and the wall time."""
    started = time.perf_counter()
    outputs = []
    here = Path.cwd()
    with tempfile.TemporaryDirectory(prefix="uavdyn_tour_") as tmp:
        os.chdir(tmp)
        try:
            for step in STEPS:
                code, printed = run(step.argv)
                if code != 0:
                    raise SystemExit(f"tour: 'uavdyn {' '.join(step.argv)}' failed "
                                     f"(exit {code}):\n{printed}")
                outputs.append((step, printed.replace(tmp + os.sep, "")))
        finally:
            os.chdir(here)
    return outputs, time.perf_counter() - started


def block(step: Step, printed: str, keep: Keep) -> list[str]:
    """The note and the console block of one step."""
    return [step.note, "", "```console", "$ uavdyn " + " ".join(step.argv),
            trimmed(printed, keep), "```", ""]


def render_readme_block(outputs: list[tuple[Step, str]]) -> str:
    """The README's tour: the text between the two markers (markers excluded)."""
    lines = ["", "<!-- written by `python analysis/tutorial_tour.py`; edit the script, not this "
             "block -->", ""]
    for step, printed in outputs:
        if step.in_readme:
            lines += block(step, printed, step.readme)
    return "\n".join(lines)


def render_page(outputs: list[tuple[Step, str]], seconds: float) -> str:
    """``docs/tutorials/tour.md``."""
    lines = [
        "# Tutorial: a five-minute tour",
        "",
        "Every command below was run by `python analysis/tutorial_tour.py` in an empty folder "
        f"(the whole run took {seconds:.0f} s on the 2-core development machine), and the "
        "output shown is what it printed, trimmed where long (a `...` line marks the cut). "
        "`python analysis/tutorial_tour.py --check` reruns it and fails if this page or the "
        "README's copy of the tour no longer matches.",
        "",
        "Install first (the repository's `README.md`: *Install and run*); the commands need no "
        "flight data and no torch.",
        "",
    ]
    for step, printed in outputs:
        lines += block(step, printed, step.page)
    lines += [
        "## Next",
        "",
        "- Your own airframe file: [the airframe file](../airframe_file.md).",
        "- Your own flight logs: [a real fixed-wing log, from import to an evaluated "
        "model](real_log.md).",
        "- What the fit prints and how to read it: [identification](../identification.md).",
        "- The learned correction and its rules: [learned correction](../learned_correction.md).",
        "- The measured results on the full emulated datasets: [results](../results.md).",
        "",
    ]
    return "\n".join(lines)


def replace_block(readme: str, new_block: str) -> str:
    """The README with the text between the markers replaced."""
    if readme.count(START) != 1 or readme.count(END) != 1 or readme.index(START) > readme.index(
            END):
        raise SystemExit(f"tour: {README.name} must hold one '{START}' before one '{END}'")
    head, rest = readme.split(START)
    _, tail = rest.split(END)
    return head + START + new_block + END + tail


# --- the comparison of --check -----------------------------------------------------------

def sections(text: str) -> list[tuple[str, list[str]]]:
    """The text cut at each ``$ uavdyn`` line: (command, its lines); the text before the
    first command is named ``(the text before the first command)``."""
    result = [("(the text before the first command)", [])]
    for line in text.splitlines():
        if line.startswith("$ uavdyn "):
            result.append((line[2:], []))
        result[-1][1].append(line)
    return result


def first_difference(expected: str, actual: str) -> str | None:
    """None if the two match; otherwise the first differing command and the line."""
    exp, act = sections(expected), sections(actual)
    for k, (name, lines) in enumerate(exp):
        if k >= len(act):
            return f"{name}: missing"
        got_name, got = act[k]
        if got_name != name:
            return f"{name}: the file has '{got_name}' in its place"
        for i in range(max(len(lines), len(got))):
            want = lines[i] if i < len(lines) else "(nothing)"
            have = got[i] if i < len(got) else "(nothing)"
            what = "a line is missing" if i >= len(lines) or i >= len(got) else \
                line_difference(want, have, REL_TOL, ABS_TOL)
            if what:
                return f"{name}: {what}\n    expected: {want}\n    the file: {have}"
    if len(act) > len(exp):
        return f"{act[len(exp)][0]}: in the file but not in the tour"
    return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="regenerate into a temporary folder and compare with README.md "
                             "and docs/tutorials/tour.md; exit 1 naming the first difference")
    parser.add_argument("--readme", type=Path, default=README, help="README to write or check")
    parser.add_argument("--page", type=Path, default=PAGE, help="tour page to write or check")
    args = parser.parse_args()
    outputs, seconds = run_tour()
    new_block, page = render_readme_block(outputs), render_page(outputs, seconds)
    readme = args.readme.read_text()
    if args.check:
        with tempfile.TemporaryDirectory(prefix="uavdyn_tour_check_") as tmp:
            (Path(tmp) / "README_block.md").write_text(new_block)
            (Path(tmp) / "tour.md").write_text(page)
            problems = []
            if not args.page.is_file():
                problems.append(f"{args.page}: missing")
            else:
                diff = first_difference(page, args.page.read_text())
                if diff:
                    problems.append(f"{args.page}: {diff}")
            diff = first_difference(new_block, readme.split(START)[1].split(END)[0]
                                    if START in readme and END in readme else "")
            if diff:
                problems.append(f"{args.readme} (tour block): {diff}")
        if problems:
            print("tour: differs from what the commands print now (rerun "
                  "`python analysis/tutorial_tour.py`):", file=sys.stderr)
            for problem in problems:
                print("  " + problem, file=sys.stderr)
            return 1
        print(f"tour: {args.readme.name} block and {args.page.name} match the commands' output "
              f"({len(outputs)} commands, {seconds:.0f} s)")
        return 0
    args.page.parent.mkdir(parents=True, exist_ok=True)
    args.page.write_text(page)
    args.readme.write_text(replace_block(readme, new_block))
    print(f"wrote {args.page} and the tour block of {args.readme} "
          f"({len(outputs)} commands, {seconds:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
