"""Elementwise operations between many rows and one row, fast and bit for bit.

numpy broadcasts a (k,) row over an (N, k) array with an inner loop of k values: for the
triads' k = 3 that loop's overhead is most of the cost (0.49 ms for 62500 rows against
0.09 ms here). :func:`rows_op` views the rows as (N / R, k R) and the row tiled R times,
so the inner loop runs over k R values; every element gets the same single operation, so
the result is the plain broadcast's, bit for bit.
"""

from __future__ import annotations

import numpy as np

#: rows per tiled row (the inner loop's length is k times this)
TILE_ROWS = 64
#: rows from which tiling (and work in place instead of new arrays) pays: fewer rows, as
#: in a daemon's read of a few samples, cost more in Python calls than they save
BIG_ROWS = 2 * TILE_ROWS


def rows_op(
    op: np.ufunc, x: np.ndarray, row: np.ndarray, out: np.ndarray | None = None
) -> np.ndarray:
    """``op(x, row)`` for ``x`` (N, k) and ``row`` (k,) (same units as ``op`` needs), into
    ``out`` (N, k) if given (it may be ``x``); any other shapes or dtypes: numpy's own
    broadcast."""
    if x.ndim != 2 or x.shape[0] < BIG_ROWS:
        return op(x, row, out=out)
    row = np.asarray(row)
    fast = (
        row.shape == x.shape[1:]
        and x.dtype == np.float64
        and row.dtype == np.float64
        and (out is None or (out.shape == x.shape and out.dtype == np.float64))
    )
    if not fast:
        return op(x, row, out=out)
    if out is None:
        out = np.empty(x.shape)
    if not out.flags.c_contiguous:
        return op(x, row, out=out)
    src = x
    if not x.flags.c_contiguous:
        np.copyto(out, x)  # a strided view: copied once, then worked on in place
        src = out
    n, k = x.shape
    m = n - n % TILE_ROWS
    op(
        src[:m].reshape(-1, k * TILE_ROWS),
        np.tile(row, TILE_ROWS),
        out=out[:m].reshape(-1, k * TILE_ROWS),
    )
    if m < n:
        op(src[m:], row, out=out[m:])
    return out


def rows_where(x: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """``x[keep]``, or ``x`` itself when ``keep`` (N,) holds every row (no copy)."""
    return x if keep.all() else x[keep]


def rows_over(x: np.ndarray, keep: np.ndarray, divisor: float) -> np.ndarray:
    """``x[keep] / divisor``, divided in place (``x`` itself when ``keep`` (N,) holds every
    row: the caller's array of its own is changed)."""
    out = rows_where(x, keep)
    out /= divisor
    return out
