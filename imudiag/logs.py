"""Sample logs (spec/sample-log.md): streaming readers and writers for CSV, NPZ, raw capture."""

from __future__ import annotations


class LogError(ValueError):
    """A log that breaks a rule of spec/sample-log.md; names file, line and reason."""

    def __init__(self, path: str, reason: str, line: int | None = None) -> None:
        self.path = path
        self.line = line
        self.reason = reason
        where = f"{path}:{line}" if line is not None else str(path)
        super().__init__(f"{where}: {reason}")
