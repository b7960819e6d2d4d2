"""MATLAB ``.mat`` files: v4-v7 through scipy, v7.3 (HDF5) through h5py (extra ``[mat]``).

The samples are one numeric matrix, N rows by k columns (a k x N matrix is
transposed when k is the shorter side), named by ``--variable NAME``, or the
only 2-D numeric variable of the file. ``--columns`` names its columns as for a
text table (``_`` skips one); without it the matrix must have 7 columns
``t gx gy gz ax ay az`` or 8 with ``temp``, or 6 without ``t`` given ``--rate``.
The whole matrix is loaded (MATLAB files are read whole by both libraries),
then handed out in blocks.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .base import DEFAULT_BLOCK_SIZE, ColumnsReader, LogError
from .extras import require
from .matrix_columns import matrix_columns
from .options import LogOptions, units_from_meta

#: First bytes of a v7.3 file (HDF5 with a 512-byte MATLAB text header).
V73_TEXT = b"MATLAB 7.3 MAT-file"


class MatReader(ColumnsReader):
    """Reader of a numeric matrix in a MATLAB ``.mat`` file."""

    time_unit_option = True  #: --time-unit reads its t column in ms, us, ns

    format = ".mat"

    def __init__(
        self,
        path: str | Path,
        block_size: int = DEFAULT_BLOCK_SIZE,
        options: LogOptions | None = None,
    ) -> None:
        super().__init__(path, block_size)
        self.options = options or LogOptions()
        head = self._read_head(128)
        self.version = "7.3" if head.startswith(V73_TEXT) else "5"
        variables = self._load_v73() if self.version == "7.3" else self._load_v5()
        self.variable, matrix = self._choose(variables)
        self._set_matrix(matrix)
        units = dict(self.options.units) or units_from_meta(self.meta)
        if units:
            self.meta["units"] = units
        self.meta.setdefault("source", f"MATLAB v{self.version} variable {self.variable!r}")

    def _load_v5(self) -> dict[str, np.ndarray]:
        scipy_io = require("scipy.io", "mat", "MATLAB .mat files")
        try:
            data = scipy_io.loadmat(self.path, squeeze_me=False)
        except (ValueError, TypeError, OSError, NotImplementedError) as exc:
            raise LogError(self.path, f"not a readable MATLAB file: {exc}") from None
        return {
            k: v for k, v in data.items() if not k.startswith("__") and isinstance(v, np.ndarray)
        }

    def _load_v73(self) -> dict[str, np.ndarray]:
        h5py = require("h5py", "mat", "MATLAB v7.3 (HDF5) .mat files")
        out: dict[str, np.ndarray] = {}
        try:
            with h5py.File(self.path, "r") as f:
                for name, item in f.items():
                    if isinstance(item, h5py.Dataset) and item.dtype.kind in "biuf":
                        out[name] = np.asarray(item[()]).T  # HDF5 holds MATLAB's transpose
        except OSError as exc:
            raise LogError(self.path, f"not a readable MATLAB v7.3 file: {exc}") from None
        return out

    def _choose(self, variables: dict[str, np.ndarray]) -> tuple[str, np.ndarray]:
        numeric = {
            k: v
            for k, v in variables.items()
            if v.dtype.kind in "biuf" and v.ndim == 2 and min(v.shape) > 1
        }
        wanted = self.options.variable
        if wanted:
            if wanted not in variables:
                raise LogError(
                    self.path,
                    f"no variable {wanted!r} (--variable); the file has {sorted(variables)}",
                )
            if wanted not in numeric:
                raise LogError(self.path, f"variable {wanted!r} is not a 2-D numeric matrix")
            return wanted, numeric[wanted]
        if len(numeric) != 1:
            listed = ", ".join(f"{k} {v.shape[0]}x{v.shape[1]}" for k, v in numeric.items())
            raise LogError(
                self.path,
                f"{len(numeric)} numeric matrices ({listed or 'none'}): choose one with "
                "--variable NAME",
            )
        return next(iter(numeric.items()))

    def _set_matrix(self, matrix: np.ndarray) -> None:
        what = f"variable {self.variable!r}"
        self._cols = matrix_columns(self.path, matrix, what, self.options, self.meta)

    def _where(self, index: int) -> str:
        return f"variable {self.variable!r} row {index + 1}"
