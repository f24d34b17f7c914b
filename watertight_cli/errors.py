"""Domain exceptions. The library raises these; the CLI turns them into one-line messages.

The library never imports click. Every error that concerns a file names it, so a line such as
``watertight: error: parts/bracket.step: not a STEP file (no ISO-10303-21 header)`` is enough
for a user to act on.
"""

from __future__ import annotations

from pathlib import Path


class WatertightError(Exception):
    """Base class of every error the library raises on purpose."""


class InputError(WatertightError):
    """An input file cannot be used: missing, empty, garbage, truncated, unknown type, no faces."""

    def __init__(self, path: str | Path, reason: str):
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


class OutputError(WatertightError):
    """An output file cannot be written (unknown type, refused overwrite, kernel write failure)."""

    def __init__(self, path: str | Path, reason: str):
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


class KernelError(WatertightError):
    """OCCT failed on an operation that should have worked (conversion, sewing, build)."""


class UsageError(WatertightError):
    """The command as given cannot run: conflicting options, an output that would overwrite an input,
    two inputs that would write the same output, a missing optional dependency. The CLI exits 2."""
