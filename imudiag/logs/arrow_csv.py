"""CSV numbers through pyarrow's parser: the compiled path of the CSV reader (issue 28).

numpy's text parser (``np.fromstring``) took half the CPU of a fleet task on a CSV log:
about 0.45 us a field, 4.5 s per 10^6 samples of ten columns, where pyarrow's CSV reader
(in the ``fleet`` extra) takes about a fifth of that on one thread. Both round each
decimal number to the nearest double, so where both read a field they read the same
value, bit for bit (tests/test_csv_arrow.py).

:func:`floats` is used by :class:`~imudiag.logs.csv_format.CsvReader` only while the
compiled kernels are on (:mod:`imudiag.kernels`: a fleet task, or ``IMUDIAG_KERNELS=numba``);
it returns None whenever it is not sure (no pyarrow, a field it cannot read, a row count
that differs, a field that is not finite), and the numpy path then reads the text as it
always did: it decides what is refused and names the line. So the reader accepts and
refuses exactly what it did, and a bad file costs one parse more.
"""

from __future__ import annotations

import io
from typing import Any

import numpy as np

#: pyarrow's csv module once imported, False where it cannot be (no pyarrow)
_ARROW: dict[str, Any] = {}


def _csv() -> Any:
    if "csv" not in _ARROW:
        try:
            import pyarrow
            import pyarrow.csv

            _ARROW["csv"], _ARROW["float64"] = pyarrow.csv, pyarrow.float64()
        except ImportError:
            _ARROW["csv"] = False
    return _ARROW["csv"]


def load() -> bool:
    """Import pyarrow's CSV reader, without parsing (Arrow's thread pools start at a parse;
    its allocator's purging thread starts with the import unless ``JE_ARROW_MALLOC_CONF``
    turns it off, as a fleet worker's environment does); whether the reader is there. The
    values are read from each column's buffer, not through ``to_numpy``, which imports
    pandas (0.2 s of a worker's start) where it is installed."""
    return bool(_csv())


def floats(text: bytes, n: int, ncols: int, used: list[int]) -> np.ndarray | None:
    """The values of columns ``used`` (indices into the ``ncols`` fields of a row) of the
    ``n`` lines of ``text`` (each ending in a newline, no comment or empty line) as an
    (n, len(used)) float64 array laid out as the numpy path's (each column contiguous);
    None where pyarrow is missing or not sure (see the module doc)."""
    pc = _csv()
    if not pc or n == 0:
        return None
    names = [f"c{i}" for i in range(ncols)]
    wanted = [names[i] for i in used]
    try:
        table = pc.read_csv(
            io.BytesIO(text),
            read_options=pc.ReadOptions(
                column_names=names, use_threads=False, block_size=len(text) + 1
            ),
            parse_options=pc.ParseOptions(
                quote_char=False,
                double_quote=False,
                escape_char=False,
                newlines_in_values=False,
                ignore_empty_lines=False,
            ),
            convert_options=pc.ConvertOptions(
                column_types={name: _ARROW["float64"] for name in wanted},
                include_columns=wanted,
                null_values=[],
                strings_can_be_null=False,
                quoted_strings_can_be_null=False,
                check_utf8=False,
            ),
        )
    except (ValueError, TypeError, OSError):  # pyarrow.ArrowInvalid is a ValueError
        return None
    if table.num_rows != n or table.num_columns != len(wanted):
        return None
    # each column contiguous, as numpy's ``values[:, used]`` lays out its copy (the blocks'
    # columns keep the strides of the numpy path)
    columns = np.empty((len(wanted), n))
    for j, column in enumerate(table.columns):
        if column.null_count:
            return None
        row = 0
        for chunk in column.chunks:  # its values buffer as numpy reads it (no copy)
            size = len(chunk)
            data = chunk.buffers()[1]
            columns[j, row : row + size] = np.frombuffer(
                data, dtype=np.float64, count=size, offset=chunk.offset * 8
            )
            row += size
    if not np.isfinite(columns).all():  # nan, inf and 1e400 spellings: numpy's to judge
        return None
    return columns.T


__all__ = ["floats", "load"]
