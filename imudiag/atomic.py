"""Files that are whole or absent: atomic writes, and outputs that never replace inputs.

A command's output goes to a temporary file in the same directory (a unique
name ``.NAME.XXXXXXXX.part``, so two writers never share one) and is renamed
over the target only when complete; on any error, Ctrl-C or SIGTERM the
temporary file is removed (and any still present at interpreter exit, as a
backstop). A command refuses an output path that is one of its inputs, or the
same file under another name, before it reads anything.
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import os
import stat
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any

from .errors import BadInput

#: Suffix of every temporary output file.
TEMP_SUFFIX = ".part"

_live: set[str] = set()  # temporaries created and not yet renamed or removed


def temp_path(path: str | os.PathLike[str]) -> str:
    """Create and return a unique, empty temporary file beside ``path``.

    Its mode is the mode of ``path`` when that exists (replacing a 0600 file keeps it
    0600), else what a new file would get. Pass it to :func:`commit` or :func:`discard`
    when done; it is removed at exit otherwise.
    """
    dest = os.fspath(path)
    directory = os.path.dirname(dest) or "."
    # the name is registered for the exit clean-up before the file exists, so a Ctrl-C or
    # SIGTERM at any point (in any thread's delivery) can never leave an unknown file behind
    for _ in range(100):
        tmp = os.path.join(
            directory, f".{os.path.basename(dest)}.{os.urandom(4).hex()}{TEMP_SUFFIX}"
        )
        _live.add(tmp)
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # umask applies
        except FileExistsError:
            _live.discard(tmp)
            continue
        except BaseException:
            discard(tmp)  # interrupted (it may exist): removed, or at exit if cut short again
            raise
        try:
            os.fchmod(fd, stat.S_IMODE(os.stat(dest).st_mode))  # the file it replaces
        except FileNotFoundError:
            pass
        except BaseException:
            os.close(fd)
            discard(tmp)
            raise
        os.close(fd)
        return tmp
    raise FileExistsError(errno.EEXIST, "no unused temporary name", directory)


def commit(tmp: str, path: str | os.PathLike[str]) -> None:
    """Give the finished temporary ``tmp`` its final name ``path`` (atomic rename)."""
    os.replace(tmp, path)
    _live.discard(tmp)


def discard(tmp: str) -> None:
    """Remove the temporary ``tmp`` (missing is fine)."""
    with contextlib.suppress(FileNotFoundError):
        os.unlink(tmp)
    _live.discard(tmp)


@atexit.register
def _remove_leftovers() -> None:
    for tmp in list(_live):
        discard(tmp)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[str]:
    """A temporary path to write; renamed to ``path`` when the block ends normally,
    removed when it ends by an exception. For libraries that write by file name
    (matplotlib, h5py, zipfile). An ``OSError`` creating it becomes :class:`BadInput`."""
    try:
        tmp = temp_path(path)
    except OSError as exc:
        raise BadInput(f"{os.fspath(path)}: cannot write: {exc.strerror or exc}") from None
    try:
        yield tmp
    except BaseException:
        discard(tmp)
        raise
    commit(tmp, path)


@contextlib.contextmanager
def atomic_open(
    path: str | os.PathLike[str], mode: str = "w", encoding: str | None = "utf-8"
) -> Iterator[IO[Any]]:
    """Open a temporary beside ``path`` for writing; it replaces ``path`` (fsync, rename)
    when the block ends normally and is removed when it ends by an exception."""
    if "b" in mode:
        encoding = None
    with atomic_path(path) as tmp, open(tmp, mode, encoding=encoding) as fh:
        yield fh
        fh.flush()
        os.fsync(fh.fileno())


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` so that it is either complete or untouched."""
    with atomic_open(path, "w") as fh:
        fh.write(text)


def save_figure(fig: Any, path: str | os.PathLike[str], **kwargs: Any) -> None:
    """``fig.savefig`` to ``path`` atomically (format from the file name, PNG by default)."""
    fmt = Path(path).suffix[1:].lower() or "png"
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=fmt, **kwargs)


def leftovers(directory: str | Path) -> list[Path]:
    """Temporary output files (``*.part``) in ``directory``: for tests and clean-up checks."""
    return sorted(p for p in Path(directory).iterdir() if p.name.endswith(TEMP_SUFFIX))


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
