"""A numeric matrix of samples (a MATLAB variable, an R matrix or data.frame) as log columns.

The samples are the rows (an unnamed k x N matrix is transposed when k is the
shorter side). Columns are named by ``--columns`` (``_`` skips one), else by
the object's own column names when they name the six sensor axes, else by
position: 7 columns ``t gx gy gz ax ay az``, 8 with ``temp``, or 6 without
``t`` given ``--rate``. ``t`` is scaled by ``--time-unit`` to seconds.
"""

from __future__ import annotations

import numpy as np

from .base import LogError
from .options import COLUMN_NAMES, TIME_UNITS, LogOptions, missing_columns


def default_columns(k: int, rate: float | None) -> list[str] | None:
    """Column names of an unnamed k-column matrix, or None when k alone cannot tell."""
    if k == 7:
        return ["t", "gx", "gy", "gz", "ax", "ay", "az"]
    if k == 8:
        return ["t", "gx", "gy", "gz", "ax", "ay", "az", "temp"]
    if k == 6 and rate is not None:
        return ["gx", "gy", "gz", "ax", "ay", "az"]
    return None


def own_names(names: list[str] | None, gyro_only: bool = False) -> list[str] | None:
    """An object's column names as log columns (others as ``_``), or None when they do not
    name every sensor axis the log needs."""
    if not names:
        return None
    mapped = [n if n in COLUMN_NAMES else "_" for n in names]
    if missing_columns(mapped, gyro_only) or len(set(mapped) - {"_"}) != len(
        [n for n in mapped if n != "_"]
    ):
        return None
    return mapped


def matrix_columns(
    path: str,
    matrix: np.ndarray,
    what: str,
    options: LogOptions,
    meta: dict,
    names: list[str] | None = None,
) -> dict[str, np.ndarray]:
    """The columns (t in s) of ``matrix``, the object ``what`` of the file ``path``.

    ``names`` are the object's own column names (already mapped by :func:`own_names`);
    ``--columns`` wins over them. Sets ``meta["sample_rate"]`` when ``t`` comes from
    ``--rate``. Raises :class:`LogError` naming the object and the reason.
    """
    m = np.asarray(matrix, dtype=float)
    if options.columns:
        names = options.columns
        if m.shape[1] != len(names) and m.shape[0] == len(names):
            m = m.T
    elif names is None:
        if m.shape[0] < m.shape[1]:
            m = m.T  # samples are the long side
        names = default_columns(m.shape[1], options.rate)
        if names is None:
            raise LogError(
                path,
                f"{what} is {m.shape[0]}x{m.shape[1]}: name its columns with --columns "
                "(e.g. t,gx,gy,gz,ax,ay,az; _ skips one)",
            )
    if m.shape[1] != len(names):
        raise LogError(path, f"--columns names {len(names)} columns, {what} has {m.shape[1]}")
    cols = {n: m[:, i] for i, n in enumerate(names) if n != "_"}
    if "t" in cols:
        cols["t"] = cols["t"] * TIME_UNITS[options.time_unit or "s"]
    elif options.rate is not None:
        cols["t"] = np.arange(m.shape[0]) / options.rate
        meta.setdefault("sample_rate", options.rate)
    else:
        raise LogError(path, "no time column: give the sample rate with --rate HZ")
    return cols
