"""The documentation checker (``analysis/check_docs.py``) catches each kind of stale statement
on a scratch tree, and the repository's own pages pass it."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _checker():
    spec = importlib.util.spec_from_file_location("check_docs", ROOT / "analysis" /
                                                  "check_docs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_each_stale_statement_is_caught_and_a_true_one_passes(tmp_path):
    check = _checker()
    (tmp_path / "docs" / "benchmarks").mkdir(parents=True)
    (tmp_path / "docs" / "page.md").write_text("# page\n")
    (tmp_path / "docs" / "benchmarks" / "b.json").write_text(
        json.dumps({"speed": {"wall_s": 54.64}, "runs": [1.5, 2.25]}))
    good = ("[ok](docs/page.md), `docs/page.md`, `uavdyn trim --airspeed 20`, "
            "55 s <!-- json docs/benchmarks/b.json speed.wall_s -->, "
            "2.3 <!-- json docs/benchmarks/b.json runs.1 -->, "
            "54640 ms <!-- json docs/benchmarks/b.json speed.wall_s 1000 -->\n")
    (tmp_path / "README.md").write_text(good)
    assert check.run(tmp_path, include_help=False) == []
    bad = ("[gone](docs/missing.md)\n`docs/benchmarks/nothing.json`\n"
           "`uavdyn trim --no-such-option 1`\n`uavdyn fly`\n"
           "56 s <!-- json docs/benchmarks/b.json speed.wall_s -->\n")
    (tmp_path / "README.md").write_text(bad)
    problems = check.run(tmp_path, include_help=False)
    assert len(problems) == 5, problems
    for expected in ("link to docs/missing.md", "path docs/benchmarks/nothing.json",
                     "has no option --no-such-option", "`uavdyn fly` is not a command",
                     "quotes 56 for speed.wall_s"):
        assert any(expected in p for p in problems), (expected, problems)


def test_a_quote_across_a_line_break_is_checked_and_a_lone_tag_is_reported(tmp_path):
    """A number at a line's end with its tag on the next line is checked like one on a single
    line (these went unchecked before); a number inside a name (``12-4-4-3``, ``3211 (1``) is
    not taken for the quote; a tag with no number right before it is reported."""
    check = _checker()
    (tmp_path / "docs" / "benchmarks").mkdir(parents=True)
    (tmp_path / "docs" / "benchmarks" / "b.json").write_text(
        json.dumps({"speed": {"wall_s": 54.64}, "n": 1}))
    tag = "<!-- json docs/benchmarks/b.json"
    page = tmp_path / "README.md"
    page.write_text(f"median 54.6\n  {tag} speed.wall_s --> ms; a turbulent 3211\n(1 {tag} n -->)"
                    f", a 12-4-4-3\n1 {tag} n -->\n")
    assert check.run(tmp_path, include_help=False) == []
    page.write_text(f"median 56.1\n  {tag} speed.wall_s --> ms\n")
    assert [p.split(": ", 1)[1] for p in check.run(tmp_path, include_help=False)] == [
        "quotes 56.1 for speed.wall_s of docs/benchmarks/b.json, which is 54.64"]
    page.write_text(f"the median, see {tag} speed.wall_s -->\n")
    problems = check.run(tmp_path, include_help=False)
    assert len(problems) == 1 and "a json tag with no number right before it" in problems[0]


def test_the_repository_documentation_passes():
    assert _checker().run(ROOT) == []
