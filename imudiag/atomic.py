"""Files that are whole or absent: atomic writes, and outputs that never replace inputs.

A command's output goes to a temporary file in the same directory (a unique
name, so two writers never share one) and is renamed over the target only when
complete; on any error, Ctrl-C or SIGTERM the temporary file is removed. A
command refuses an output path that is one of its inputs, or the same file
under another name, before it reads anything.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

from .errors import BadInput


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` so that it is either complete or untouched."""
    target = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent or ".")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _same(a: str, b: str) -> bool:
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def refuse_overwrite(
    inputs: Iterable[tuple[str, str | None]], outputs: Iterable[tuple[str, str | None]]
) -> None:
    """BadInput when an output path (``(option, path)``; ``-`` and None skipped) is an input
    path or another output's path."""
    ins = [(k, v) for k, v in inputs if v and v != "-"]
    outs = [(k, v) for k, v in outputs if v and v != "-"]
    for i, (ko, vo) in enumerate(outs):
        for ki, vi in ins:
            if _same(vo, vi):
                raise BadInput(
                    f"{vo}: {ko} is the input {ki}: refusing to overwrite an input "
                    "(choose another output path)"
                )
        for ko2, vo2 in outs[i + 1 :]:
            if _same(vo, vo2):
                raise BadInput(f"{vo}: {ko} and {ko2} name the same file")
