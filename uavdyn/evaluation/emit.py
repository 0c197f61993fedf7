"""How a benchmark script hands over its result: the machine it ran on and the JSON printed
and, where asked, written (one definition for the analysis scripts, which may not import each
other)."""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path


def machine_facts() -> dict:
    """The platform, the core count and the 1-minute load now (timings name their machine)."""
    return {"platform": platform.platform(), "cpus": os.cpu_count(),
            "load_1min_after": os.getloadavg()[0]}


def emit_json(doc: dict, out: str | Path | None = None) -> str:
    """Print ``doc`` as indented JSON and, with ``out``, write it there (a temporary sibling
    renamed into place); returns the text."""
    text = json.dumps(doc, indent=2)
    print(text)
    if out:
        path = Path(out)
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(text + "\n")
        tmp.replace(path)
    return text
