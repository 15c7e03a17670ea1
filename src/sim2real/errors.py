"""Errors raised for bad user input.

Every error names the offending file, the element/column/key and the fix, so that the
message alone is enough to repair the input.
"""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad user input: a file, the element in it, what is wrong and how to fix it."""

    def __init__(self, path: str | Path | None, where: str | None, problem: str, fix: str) -> None:
        self.path = str(path) if path is not None else None
        self.where = where
        self.problem = problem
        self.fix = fix
        location = self.path or "<input>"
        if where:
            location = f"{location}: {where}"
        super().__init__(f"{location}: {problem}. Fix: {fix}")

    def __reduce__(self) -> tuple[type, tuple[str | None, str | None, str, str]]:
        # Rebuilt from its parts when it crosses a process (sim2real.forked), not from its message.
        return (type(self), (self.path, self.where, self.problem, self.fix))
