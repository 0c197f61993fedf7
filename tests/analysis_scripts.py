"""Loading a script of ``analysis/`` as a module in a test (the scripts are not a package; one
that imports a sibling by name finds it once the sibling is loaded here first)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ANALYSIS = Path(__file__).resolve().parent.parent / "analysis"


def load_script(name: str) -> ModuleType:
    """``analysis/<name>.py`` as the module ``name`` (registered, for its siblings)."""
    spec = importlib.util.spec_from_file_location(name, ANALYSIS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
