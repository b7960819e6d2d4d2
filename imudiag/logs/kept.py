"""The last parse of a log file, kept while the file is unchanged.

A log is read more than once in one process: once per IMU instance (the fleet diagnoses
each), and by each pass of a diagnosis (the noise figures, then the windows). Readers
whose format is parsed whole (the DataFlash scan, pyulog's ULog) keep their last parse
here and give it again while the file's resolved path, size and modification time (ns)
and the reader's own key are unchanged. Its arrays are made read-only (every reader of the
log shares them); a parse larger than its ``max_bytes`` is not kept.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np

T = TypeVar("T")

#: the largest parse kept by default, bytes of its arrays (a longer log is parsed again)
KEEP_BYTES = 256 * 2**20


class LastParse(Generic[T]):
    """One reader kind's last parse (module docstring)."""

    def __init__(self, arrays: Callable[[T], Iterable[np.ndarray]], max_bytes: int = KEEP_BYTES):
        self._arrays = arrays  #: the parse's numpy arrays (their bytes, made read-only)
        self.max_bytes = max_bytes
        self._key: tuple[Any, ...] | None = None
        self._value: T | None = None

    def get(self, path: str | Path, key: Any, parse: Callable[[], T]) -> T:
        """The parse of ``path`` under the reader's ``key``: the kept one while the file is
        unchanged, else ``parse()`` (kept when at most :attr:`max_bytes`)."""
        st = Path(path).stat()
        full = (str(Path(path).resolve()), st.st_size, st.st_mtime_ns, key)
        if self._key == full:
            assert self._value is not None
            return self._value
        value = parse()
        self.forget()
        arrays = list(self._arrays(value))
        if sum(a.nbytes for a in arrays) <= self.max_bytes:
            for a in arrays:
                a.flags.writeable = False
            self._key, self._value = full, value
        return value

    def forget(self) -> None:
        """Drop the kept parse (its memory; a benchmark's cold read)."""
        self._key, self._value = None, None


__all__ = ["KEEP_BYTES", "LastParse"]
