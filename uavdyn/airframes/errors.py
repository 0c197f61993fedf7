"""The error of a malformed airframe file, and how values and paths appear in its message."""

from __future__ import annotations

from pathlib import Path


class AirframeError(ValueError):
    """A parameter file is malformed; the one-line message names the file and the key."""

    def __init__(self, message: str) -> None:
        super().__init__(" ".join(message.split()))


def _display(path: str | Path) -> str:
    """A path as it can appear on one line of a message (non-printable characters escaped)."""
    text = str(path)
    return text if text.isprintable() else repr(text)[1:-1]


def _short(value: object, limit: int = 40) -> str:
    """A short printable repr of a value for a message (never a whole file's content)."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."
