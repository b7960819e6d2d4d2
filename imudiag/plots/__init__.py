"""PNG figures of the commands (``--plots DIR``; needs matplotlib, the ``plots`` extra).

Shared ground of :mod:`.diagnosis` (``imudiag diagnose``), :mod:`.calibration`
(``imudiag calibrate``) and :mod:`imudiag.modelcheck.plots` (``imudiag model-check``):
the check that matplotlib is installed and that the directory can take the files, both
made before any work; pyplot on the Agg backend (no display); figures saved atomically.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from .. import atomic
from ..errors import BadInput
from ..logs.extras import MissingExtra

#: The optional extra that installs matplotlib.
EXTRA = "plots"
#: Resolution of the PNG files, dots per inch (figure sizes are in inches).
DPI = 100


def available() -> bool:
    """Whether matplotlib can be imported."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return False
    return True


def require(option: str = "--plots") -> None:
    """:class:`~imudiag.logs.extras.MissingExtra` (exit 2) naming the pip command when
    matplotlib is not installed."""
    if not available():
        raise MissingExtra(
            f"{option}: drawing figures needs the Python package 'matplotlib', not installed: "
            f"pip install 'imudiag[{EXTRA}]'"
        )


def check_directory(path: str | os.PathLike[str], option: str = "--plots") -> Path:
    """``path`` as a directory the figures can go to: an existing writable directory, or one
    that can be created (its nearest existing ancestor is a writable directory). Nothing is
    created here. :class:`~imudiag.errors.BadInput` with a one-line reason otherwise."""
    p = Path(path)
    name = os.fspath(path)
    if p.exists():
        if not p.is_dir():
            raise BadInput(f"{name}: {option}: not a directory (a file of that name exists)")
        if not os.access(p, os.W_OK | os.X_OK):
            raise BadInput(f"{name}: {option}: the directory is not writable")
        return p
    parent = p.absolute().parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise BadInput(
            f"{name}: {option}: cannot create the directory: {parent} is not a directory"
        )
    if not os.access(parent, os.W_OK | os.X_OK):
        raise BadInput(f"{name}: {option}: cannot create the directory: {parent} is not writable")
    return p


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (files only, never a display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig: Any, directory: str | os.PathLike[str], name: str, dpi: int = DPI) -> Path:
    """Save ``fig`` as ``directory/name`` atomically (the directory created) and close it."""
    out_dir = Path(directory)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BadInput(f"{out_dir}: cannot create the directory: {exc.strerror or exc}") from None
    path = out_dir / name
    try:
        atomic.save_figure(fig, path, dpi=dpi)
    finally:
        pyplot().close(fig)
    return path


__all__ = ["DPI", "EXTRA", "available", "check_directory", "pyplot", "require", "save"]
