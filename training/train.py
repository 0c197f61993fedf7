"""``python -m training.train [options]``: the same options as ``uavdyn train`` (one parser).

Example::

    python -m training.train --airframe f450 --dataset DIR --out results/f450_improved.npz
"""

from __future__ import annotations

import sys

from uavdyn.cli import main as cli_main


def main(argv: list[str] | None = None) -> int:
    """Run ``uavdyn train`` with ``argv`` (default: the command line)."""
    return cli_main(["train", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    raise SystemExit(main())
