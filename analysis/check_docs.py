"""Check that the documentation says only what exists: every link, file path and command the
README, the docs pages and the ``--help`` texts mention, and every number they quote from a
benchmark JSON file.

* **links**: a Markdown link to a relative target must name a file or folder that exists;
* **paths**: a path in backticks (or a ``--help`` text) under a folder of the repository
  (``uavdyn/``, ``docs/``, ``examples/``, ``analysis/``, ``tests/``, ``data/``, ``.ci/``,
  ``training/``) must exist (patterns with ``*``, ``<``, ``{`` or ``...`` are skipped);
* **commands**: ``uavdyn SUBCOMMAND --option ...`` in backticks or code blocks must name a
  subcommand that exists and options it has;
* **quoted numbers**: a number followed by ``<!-- json FILE KEY.PATH -->`` must equal the value
  at that key of that JSON file to the digits quoted (``KEY.PATH`` uses dots, list indices are
  numbers, ``~`` stands for a space in a key; an optional third word scales the JSON value,
  e.g. ``1000`` for s -> ms).

Prints one line per problem (file:line: what) and exits 1 if there is any::

    python analysis/check_docs.py
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("uavdyn/", "docs/", "examples/", "analysis/", "tests/", "data/", ".ci/",
           "training/")
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")
TICKED = re.compile(r"`([^`\n]+)`")
PATH = re.compile(r"(?:(?<=[\s(`'\"])|^)((?:uavdyn|docs|examples|analysis|tests|data|\.ci|"
                  r"training)/[A-Za-z0-9_./+-]*[A-Za-z0-9_/])")
COMMAND = re.compile(r"(?:^|[$;&|(]\s*)uavdyn ([a-z][a-z-]+)((?: +[^\s`|;&]+)*)")
QUOTE = re.compile(r"(?<![\w.])(-?\d+(?:\.\d+)?(?:[eE][+-]?\d+)?)\s*(?:[^\s<\d]{0,6}\s*)?"
                   r"<!--\s*json\s+(\S+)\s+(\S+)(?:\s+(\S+))?\s*-->")
TAG = re.compile(r"<!--\s*json\s+(\S+\s+\S+)")
SKIP = ("*", "<", "{", "...", "$", "_build")  # patterns, placeholders, build outputs


def documents(root: Path) -> list[Path]:
    """README, CONTRIBUTING and every Markdown page under docs/ (not the built site)."""
    pages = [root / "README.md", root / "CONTRIBUTING.md"]
    pages += sorted(p for p in (root / "docs").rglob("*.md") if "_build" not in p.parts)
    return [p for p in pages if p.is_file()]


def help_texts() -> dict[str, str]:
    """``uavdyn --help`` and each subcommand's ``--help``, by name."""
    from uavdyn.cli.app import build_parser

    parser = build_parser()
    texts = {"uavdyn --help": parser.format_help()}
    for action in parser._subparsers._group_actions:  # the subcommands
        for name, sub in action.choices.items():
            texts[f"uavdyn {name} --help"] = sub.format_help()
    return texts


def command_options() -> dict[str, set[str]]:
    """Each subcommand's option strings."""
    from uavdyn.cli.app import build_parser

    out = {}
    for action in build_parser()._subparsers._group_actions:
        for name, sub in action.choices.items():
            out[name] = {o for a in sub._actions for o in a.option_strings}
    return out


def check_links(page: Path, lines: list[str]) -> list[str]:
    problems = []
    for n, line in enumerate(lines, 1):
        for match in LINK.finditer(line):
            target = (match.group(1) or match.group(2)).split("#")[0]
            if not target or re.match(r"[a-z]+:", target):
                continue
            if not (page.parent / target).exists():
                problems.append(f"{_rel(page)}:{n}: link to {target}, which does not exist")
    return problems


def check_paths(where: str, lines: list[str], root: Path) -> list[str]:
    problems = []
    for n, line in enumerate(lines, 1):
        candidates = [m.group(1) for m in TICKED.finditer(line)] if where.endswith(".md") \
            else [line]
        for text in candidates:
            for match in PATH.finditer(" " + text):
                path = match.group(1).rstrip(".")
                if any(s in text for s in SKIP) or "//" in path:
                    continue
                if not (root / path).exists() and not any(  # an --out prefix of files
                        (root / path).with_name((root / path).name + ext).exists()
                        for ext in (".json", ".md")):
                    problems.append(f"{where}:{n}: path {path} does not exist")
    return problems


def check_commands(where: str, lines: list[str], options: dict[str, set[str]]) -> list[str]:
    problems = []
    in_code = False
    for n, line in enumerate(lines, 1):
        if line.lstrip().startswith("```"):
            in_code = not in_code
            continue
        texts = [line] if in_code else [m.group(1) for m in TICKED.finditer(line)]
        for text in texts:
            for match in COMMAND.finditer(text):
                sub, rest = match.group(1), match.group(2)
                if sub not in options:
                    problems.append(f"{where}:{n}: `uavdyn {sub}` is not a command")
                    continue
                for word in rest.split():
                    option = word.split("=")[0]
                    if option.startswith("--") and option not in options[sub] \
                            and not any(s in option for s in SKIP):
                        problems.append(f"{where}:{n}: uavdyn {sub} has no option {option}")
    return problems


def _value(data, key: str):
    """The value at a dotted key (``~`` stands for a space in a key: ``nominal~physics``)."""
    for part in key.split("."):
        data = data[int(part)] if isinstance(data, list) else data[part.replace("~", " ")]
    return data


def _agrees(quoted: str, value: float) -> bool:
    """``value`` shows as ``quoted`` at the quoted number of decimals (or of significant
    digits, for a number written with an exponent)."""
    q = float(quoted)
    if "e" in quoted.lower():
        digits = len(quoted.lower().split("e")[0].replace("-", "").replace(".", "")) - 1
        return math.isclose(float(f"{value:.{digits}e}"), q, rel_tol=1e-12)
    decimals = len(quoted.split(".")[1]) if "." in quoted else 0
    return abs(value - q) <= 0.5 * 10 ** -decimals * (1 + 1e-9)  # either rounding of a half


def check_quotes(page: Path, lines: list[str], root: Path) -> list[str]:
    """Every ``NUMBER <!-- json FILE KEY [SCALE] -->`` of the page, the number and its tag on
    one line or across a line break, against the value it names; and every ``json`` tag
    with no number right before it (a tag that checks nothing)."""
    problems = []
    text = "\n".join(lines)
    matched = set()
    for match in QUOTE.finditer(text):
        quoted, file, key, scale = match.groups()
        n = text.count("\n", 0, match.start(1)) + 1
        matched.add(text.index("<!--", match.end(1)))
        path = root / file
        try:
            value = float(_value(json.loads(path.read_text()), key)) * float(scale or 1)
        except (OSError, ValueError, KeyError, IndexError, TypeError) as exc:
            problems.append(f"{_rel(page)}:{n}: cannot read {key} of {file} ({exc})")
            continue
        if not _agrees(quoted, value):
            problems.append(f"{_rel(page)}:{n}: quotes {quoted} for {key} of {file}, "
                            f"which is {value:.6g}")
    for tag in TAG.finditer(text):
        if tag.start() not in matched:
            n = text.count("\n", 0, tag.start()) + 1
            problems.append(f"{_rel(page)}:{n}: a json tag with no number right before it "
                            f"({tag.group(1)})")
    return problems


def _rel(path: Path) -> str:
    try:
        return str(path.relative_to(ROOT))
    except ValueError:
        return str(path)


def run(root: Path, include_help: bool = True) -> list[str]:
    """Every problem found, one line each (``include_help``: also the ``--help`` texts)."""
    options = command_options()
    problems: list[str] = []
    for page in documents(root):
        lines = page.read_text().splitlines()
        problems += check_links(page, lines)
        problems += check_paths(_rel(page), lines, root)
        problems += check_commands(_rel(page), lines, options)
        problems += check_quotes(page, lines, root)
    for name, text in help_texts().items() if include_help else []:
        lines = text.splitlines()
        problems += check_paths(name, lines, root)
    return problems


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=ROOT, help="repository root")
    args = parser.parse_args()
    problems = run(args.root.resolve())
    for line in problems:
        print(line)
    pages = len(documents(args.root.resolve()))
    print(f"checked {pages} pages and the --help texts: {len(problems)} problem(s)",
          file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
