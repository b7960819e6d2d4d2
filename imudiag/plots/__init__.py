"""PNG figures of the commands (``--plots DIR``; needs matplotlib, the ``plots`` extra).

Shared ground of :mod:`.diagnosis` (``imudiag diagnose``), :mod:`.calibration`
(``imudiag calibrate``) and :mod:`imudiag.modelcheck.plots` (``imudiag model-check``):
the check that matplotlib is installed and that the directory can take the files, both
made before any work; pyplot on the Agg backend (no display); the layout and saving rules
of every figure (:func:`save`): figures laid out, their log-axis labels drawn without
mathtext, saved atomically.
"""

from __future__ import annotations

import functools
import os
import re
from pathlib import Path
from typing import Any

from .. import atomic
from ..errors import BadInput
from ..logs.extras import MissingExtra

#: The optional extra that installs matplotlib.
EXTRA = "plots"
#: Resolution of the PNG files, dots per inch (figure sizes are in inches).
DPI = 100
#: zlib level of the PNG files (0-9): 3 encodes in about 60 % of the time of Pillow's
#: default 6 for files 5-8 % larger (the figures of the three commands, 2026-11-29)
PNG_COMPRESS_LEVEL = 3
#: :func:`layout`'s padding around the decorations of each axes and the figure's edge, as a
#: fraction of the font size (``tight_layout``'s default)
PAD = 1.08
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


_SUPERSCRIPT = str.maketrans(
    "0123456789-", "\u2070\u00b9\u00b2\u00b3\u2074\u2075\u2076\u2077\u2078\u2079\u207b"
)
_MATH_LABEL = re.compile(r"\$\\mathdefault\{(-?)(?:([0-9.]+)\\times)?([0-9]+)\^\{(-?[0-9]+)\}\}\$")


def plain_log_label(label: str) -> str:
    """A log axis' mathtext tick label (``$\\mathdefault{2\\times10^{-3}}$``) as plain text
    with Unicode superscripts (``2×10⁻³``); any other label unchanged."""
    m = _MATH_LABEL.fullmatch(label)
    if m is None:
        return label
    sign, mantissa, base, exponent = m.groups()
    head = f"{mantissa}×" if mantissa else ""
    return f"{'−' if sign else ''}{head}{base}{exponent.translate(_SUPERSCRIPT)}"


@functools.cache
def _font_has_superscripts() -> bool:
    """Whether the default font draws the superscript digits and minus (matplotlib's
    DejaVu Sans does; a matplotlibrc may name another font)."""
    from matplotlib.font_manager import FontProperties, findfont, get_font

    font = get_font(findfont(FontProperties()))
    return all(font.get_char_index(ord(c)) for c in "0123456789-".translate(_SUPERSCRIPT))


@functools.cache
def _plain_formatter_class() -> Any:
    from matplotlib import ticker

    class PlainLogFormatter(ticker.Formatter):
        """The labels of matplotlib's log-axis formatter ``inner`` (the same ticks labelled,
        the same numbers) in plain text: a label in mathtext costs a parse of about 10 ms
        (pyparsing), a third of a model check's figures."""

        def __init__(self, inner: Any) -> None:
            self.inner = inner

        def set_axis(self, axis: Any) -> None:
            super().set_axis(axis)
            self.inner.set_axis(axis)

        def set_locs(self, locs: Any) -> None:
            self.inner.set_locs(locs)

        def __call__(self, x: float, pos: int | None = None) -> str:
            return plain_log_label(self.inner(x, pos))

        def format_data(self, value: float) -> str:
            return plain_log_label(self.inner.format_data(value))

        def format_data_short(self, value: float) -> str:
            return plain_log_label(self.inner.format_data_short(value))

    return PlainLogFormatter


def plain_log_labels(fig: Any) -> None:
    """Give each log axis of ``fig`` labelled by matplotlib's default (mathtext) formatter
    the same labels in plain text (:func:`plain_log_label`), where the font has the
    superscripts and TeX is not asked for."""
    from matplotlib import rcParams, ticker

    if rcParams["text.usetex"]:
        return
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            major, minor = axis.get_major_formatter(), axis.get_minor_formatter()
            log = ticker.LogFormatterSciNotation
            if (type(major) is log or type(minor) is log) and not _font_has_superscripts():
                return
            if type(major) is log:
                axis.set_major_formatter(_plain_formatter_class()(major))
            if type(minor) is log:
                axis.set_minor_formatter(_plain_formatter_class()(minor))


def layout(
    fig: Any, rect: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 1.0), pad: float = PAD
) -> None:
    """Apply ``fig.tight_layout(rect=rect, pad=pad)``'s subplot parameters (``rect`` in
    figure fractions: the box the axes and their decorations fit into; ``pad`` in font
    sizes) from one measurement of each axes instead of matplotlib's two: with a box it
    measures the unchanged figure a second time. Half its cost, the same parameters
    (tests/test_plots.py compares them). For the figures of :func:`subplots` (axes of one
    grid); any other figure, or one the decorations do not fit, gets ``fig.tight_layout``."""
    import numpy as np
    from matplotlib import rcParams
    from matplotlib.font_manager import FontProperties
    from matplotlib.gridspec import SubplotSpec
    from matplotlib.transforms import Bbox

    groups: dict[Any, list[Any]] = {}  # axes sharing a cell (twins) measured as one
    for ax in fig.axes:
        ss = ax.get_subplotspec()
        if not isinstance(ss, SubplotSpec) or ax.get_axes_locator() is not None:
            groups = {}
            break
        groups.setdefault(ss, []).append(ax)
    grids = {id(ss.get_gridspec()) for ss in groups}
    if len(grids) != 1:
        fig.tight_layout(rect=rect, pad=pad)
        return
    rows, cols = next(iter(groups)).get_gridspec().get_geometry()
    renderer = fig.canvas.get_renderer()
    to_fig = fig.transFigure.inverted()
    # room the decorations take beyond each cell's axes box (figure fractions), as matplotlib
    hspaces = np.zeros((rows, cols + 1))
    vspaces = np.zeros((rows + 1, cols))
    for ss, members in groups.items():
        shown = [ax for ax in members if ax.get_visible()]
        if not shown:
            continue
        box = ss.get_position(fig)
        tight = to_fig.transform_bbox(
            Bbox.union([ax.get_tightbbox(renderer, for_layout_only=True) for ax in shown])
        )
        r, c = ss.rowspan, ss.colspan
        hspaces[r, c.start] += box.xmin - tight.xmin
        hspaces[r, c.stop] += tight.xmax - box.xmax
        vspaces[r.start, c] += tight.ymax - box.ymax
        vspaces[r.stop, c] += box.ymin - tight.ymin
    width, height = fig.get_size_inches()
    pad_inch = pad * FontProperties(size=rcParams["font.size"]).get_size_in_points() / 72
    pad_w, pad_h = pad_inch / width, pad_inch / height

    def extent(text: Any, along: str) -> float:
        if not text or not text.get_in_layout():
            return 0.0
        bbox = to_fig.transform_bbox(text.get_window_extent(renderer))
        return float(getattr(bbox, along)) + (pad_w if along == "width" else pad_h)

    # matplotlib's first pass (the whole figure), then its second (the box): margins grown by
    # the box's, the gaps between cells measured once serving both
    left = max(hspaces[:, 0].max(), 0) + pad_w + extent(fig._supylabel, "width") + rect[0]
    right = max(hspaces[:, -1].max(), 0) + pad_w + (1 - rect[2])
    top = max(vspaces[0, :].max(), 0) + pad_h + extent(fig._suptitle, "height") + (1 - rect[3])
    bottom = max(vspaces[-1, :].max(), 0) + pad_h + extent(fig._supxlabel, "height") + rect[1]
    params = {"left": left, "right": 1 - right, "bottom": bottom, "top": 1 - top}
    fits = left + right < 1 and bottom + top < 1
    if cols > 1:
        gap = hspaces[:, 1:-1].max() + pad_w
        cell = (1 - right - left - gap * (cols - 1)) / cols
        fits = fits and cell > 0
        params["wspace"] = gap / cell if fits else 0.0
    if rows > 1:
        gap = vspaces[1:-1, :].max() + pad_h
        cell = (1 - top - bottom - gap * (rows - 1)) / rows
        fits = fits and cell > 0
        params["hspace"] = gap / cell if fits else 0.0
    if not fits:
        fig.tight_layout(rect=rect, pad=pad)  # its warning names what does not fit
        return
    fig.subplots_adjust(**params)


def save(
    fig: Any,
    directory: str | os.PathLike[str],
    name: str,
    dpi: int = DPI,
    rect: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 1.0),
) -> Path:
    """Lay ``fig`` out (:func:`layout` in ``rect``, figure fractions: room left for a title
    or a note; log axes labelled in plain text, :func:`plain_log_labels`), save it as
    ``directory/name`` at ``dpi`` atomically (the directory created; PNG at
    :data:`PNG_COMPRESS_LEVEL`) and close it. Make the figure with :func:`subplots` at the
    same ``dpi``."""
    out_dir = Path(directory)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BadInput(f"{out_dir}: cannot create the directory: {exc.strerror or exc}") from None
    path = out_dir / name
    try:
        plain_log_labels(fig)
        layout(fig, rect)
        # the layout is done: without an engine left on the figure, savefig draws it once
        # (with one, it draws it a first time to lay it out again)
        fig.set_layout_engine(None)
        kwargs = (
            {"pil_kwargs": {"compress_level": PNG_COMPRESS_LEVEL}} if name.endswith(".png") else {}
        )
        atomic.save_figure(fig, path, dpi=dpi, **kwargs)
    finally:
        pyplot().close(fig)
    return path


__all__ = [
    "DPI",
    "EXTRA",
    "PAD",
    "PNG_COMPRESS_LEVEL",
    "TITLE_ROOM",
    "available",
    "check_directory",
    "layout",
    "plain_log_label",
    "plain_log_labels",
    "pyplot",
    "require",
    "save",
    "subplots",
]
