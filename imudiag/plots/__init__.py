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
#: :func:`save`'s layout box for a figure with a title over its axes (``suptitle``): the
#: top 3 % left to it (figure fractions: left, bottom, right, top)
TITLE_ROOM = (0.0, 0.0, 1.0, 0.97)


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


def subplots(*args: Any, dpi: int = DPI, **kwargs: Any) -> tuple[Any, Any]:
    """``pyplot.subplots(...)`` of a figure made at ``dpi``, the resolution :func:`save`
    writes it at (figure sizes in inches): the layout pass of :func:`save` and the drawing
    then measure each text at one resolution, so matplotlib's text caches serve the second
    (a model check's 17 figures: about a fifth less time)."""
    return pyplot().subplots(*args, dpi=dpi, **kwargs)


def save(
    fig: Any,
    directory: str | os.PathLike[str],
    name: str,
    dpi: int = DPI,
    rect: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 1.0),
) -> Path:
    """Lay ``fig`` out (``tight_layout`` in ``rect``, figure fractions: room left for a
    title or a note), save it as ``directory/name`` at ``dpi`` atomically (the directory
    created) and close it. Make the figure with :func:`subplots` at the same ``dpi``."""
    out_dir = Path(directory)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BadInput(f"{out_dir}: cannot create the directory: {exc.strerror or exc}") from None
    path = out_dir / name
    try:
        fig.tight_layout(rect=rect)
        # the layout is done: without an engine left on the figure, savefig draws it once
        # (with one, it draws it a first time to lay it out again)
        fig.set_layout_engine(None)
        atomic.save_figure(fig, path, dpi=dpi)
    finally:
        pyplot().close(fig)
    return path


__all__ = [
    "DPI",
    "EXTRA",
    "TITLE_ROOM",
    "available",
    "check_directory",
    "pyplot",
    "require",
    "save",
    "subplots",
]
