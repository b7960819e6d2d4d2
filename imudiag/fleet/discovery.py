"""Which files a fleet run diagnoses: paths, folders (searched recursively) and globs,
each log with the SHA-256 of its content (the key that lets a run resume)."""

from __future__ import annotations

import glob
import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

from ..errors import BadInput
from ..logs import LogError, lookup

#: Files in a fleet folder that are never logs (the fleet's own and the simulator's).
NOT_LOGS = ("certificate.yaml", "certificate.yml", "truth.json", "SOURCE.md")
#: Bytes read per step when hashing a log.
HASH_CHUNK = 1 << 20


@dataclass(frozen=True)
class LogFile:
    """One log found: its path, size (bytes), modification time (ns) and content hash."""

    path: str
    size: int
    mtime_ns: int
    sha256: str


def sha256_of(path: str | Path) -> str:
    """The SHA-256 of a file's bytes (of a directory's files, in name order: a ROS 2 bag)."""
    h = hashlib.sha256()
    p = Path(path)
    files = sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else [p]
    for f in files:
        if p.is_dir():
            h.update(str(f.relative_to(p)).encode() + b"\0")
        with open(f, "rb") as fh:
            while chunk := fh.read(HASH_CHUNK):
                h.update(chunk)
    return h.hexdigest()


def _is_log(path: Path) -> bool:
    if path.name in NOT_LOGS or path.name.startswith("."):
        return False
    try:
        lookup(path)
    except LogError:
        return False
    return True


def _walk(folder: Path) -> list[Path]:
    """The logs below ``folder``: files of a known format, and ROS 2 bag directories."""
    found: list[Path] = []
    for entry in sorted(folder.iterdir()):
        if entry.name.startswith("."):
            continue
        if entry.is_dir():
            if (entry / "metadata.yaml").is_file() and _is_log(entry):
                found.append(entry)
            else:
                found.extend(_walk(entry))
        elif entry.is_file() and _is_log(entry):
            found.append(entry)
    return found


def expand(paths: list[str]) -> list[Path]:
    """The logs named by ``paths`` (files, folders searched recursively, globs), each once,
    in the order given. BadInput for a path or glob that names nothing."""
    out: list[Path] = []
    seen: set[str] = set()
    for text in paths:
        if any(c in text for c in "*?["):
            matches = [Path(m) for m in sorted(glob.glob(text, recursive=True))]
            if not matches:
                raise BadInput(f"{text}: the pattern matches no file")
        else:
            matches = [Path(text)]
            if not matches[0].exists():
                raise BadInput(f"{text}: no such file or directory")
        for m in matches:
            if m.is_dir() and not (m / "metadata.yaml").is_file():
                logs = _walk(m)
            elif m.is_dir() or _is_log(m) or m.is_file():
                logs = [m]  # a file named on purpose is a row, even in an unknown format
            else:
                logs = []
            for log in logs:
                key = os.path.realpath(log)
                if key not in seen:
                    seen.add(key)
                    out.append(log)
    if not out:
        raise BadInput(f"{' '.join(paths)}: no log found")
    return out


def key_of(path: Path) -> tuple[str, int, int]:
    """(path, size in bytes, modification time in ns) of a log (a directory's files summed)."""
    st = path.stat()
    size = st.st_size
    if path.is_dir():
        size = sum(q.stat().st_size for q in path.rglob("*") if q.is_file())
    return (str(path), size, st.st_mtime_ns)


def describe(path: Path, known: dict[tuple[str, int, int], str] | None = None) -> LogFile:
    """The :class:`LogFile` of ``path``; ``known`` maps (path, size, mtime_ns) to a hash
    already computed (a resumed run does not read unchanged logs twice)."""
    key = key_of(path)
    digest = (known or {}).get(key) or sha256_of(path)
    return LogFile(key[0], key[1], key[2], digest)


__all__ = ["LogFile", "describe", "expand", "key_of", "sha256_of"]
