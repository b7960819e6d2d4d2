"""R data files: ``.rda`` / ``.RData`` (R's ``save``) and ``.rds`` (``saveRDS``), read through
the pure-Python ``rdata`` package (extra ``[r]``).

The samples are one object of the file: a data.frame, or a numeric matrix with
named or unnamed columns, named by ``--variable NAME`` or the only such object
of an ``.rda`` (an ``.rds`` holds one object). Columns named ``t gx gy gz ax ay
az`` (``temp`` optional; others ignored) are used by name; otherwise, or with
``--columns``, by position as for a MATLAB matrix
(:mod:`imudiag.logs.matrix_columns`). The whole file is loaded (R's formats are
read whole), then handed out in blocks.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .base import DEFAULT_BLOCK_SIZE, ColumnsReader, LogError
from .extras import require
from .matrix_columns import matrix_columns, own_names
from .options import LogOptions, units_from_meta

#: Endings of files written by R's ``save`` (one or more named objects).
RDA_ENDINGS = (".rda", ".rdata")
#: Ending of a file written by R's ``saveRDS`` (one unnamed object).
RDS_ENDING = ".rds"


class _Table:
    """One 2-D numeric object of an R file: its values (rows are samples) and column names."""

    def __init__(self, kind: str, values: np.ndarray, names: list[str] | None) -> None:
        self.kind = kind  #: data.frame or matrix
        self.values = values
        self.names = names

    def describe(self, name: str) -> str:
        return f"{name} ({self.kind} {self.values.shape[0]}x{self.values.shape[1]})"


def _as_table(obj: Any) -> _Table | None:
    """The object as a numeric table, or None when it is not a data.frame or a 2-D matrix."""
    names: list[str] | None = None
    if hasattr(obj, "columns") and hasattr(obj, "to_numpy"):  # a data.frame (pandas)
        names = [str(c) for c in obj.columns]
        raw = [np.asarray(obj[c].to_numpy()) for c in obj.columns]
        if len(raw) < 2 or all(v.dtype.kind not in "biuf" for v in raw):
            return None
        # a column that is not numeric (text, factor) reads as NaN: an error if it is used
        cols = [v.astype(float) if v.dtype.kind in "biuf" else np.full(len(v), np.nan) for v in raw]
        return _Table("data.frame", np.column_stack(cols), names)
    if hasattr(obj, "dims") and hasattr(obj, "coords") and hasattr(obj, "values"):  # xarray
        values = np.asarray(obj.values)
        if values.ndim == 2 and obj.dims[1] in obj.coords:
            names = [str(n) for n in np.asarray(obj.coords[obj.dims[1]].values)]
        obj = values
    if isinstance(obj, np.ndarray) and obj.ndim == 2 and obj.dtype.kind in "biuf":
        if min(obj.shape) > 1:
            return _Table("matrix", obj.astype(float), names)
    return None


class RDataReader(ColumnsReader):
    """Reader of a data.frame or numeric matrix in an R ``.rda`` / ``.RData`` / ``.rds`` file."""

    time_unit_option = True  #: --time-unit reads its t column in ms, us, ns

    format = "rdata"

    def __init__(
        self,
        path: str | Path,
        block_size: int = DEFAULT_BLOCK_SIZE,
        options: LogOptions | None = None,
    ) -> None:
        super().__init__(path, block_size)
        self.options = options or LogOptions()
        objects = self._load()
        self.variable, table = self._choose(objects)
        names = None if self.options.columns else own_names(table.names, self.options.gyro_only)
        what = f"{table.kind} {self.variable!r}" if self.variable else f"the {table.kind}"
        self._cols = matrix_columns(
            self.path, table.values, what, self.options, self.meta, names=names
        )
        empty = [n for n, v in self._cols.items() if len(v) and np.isnan(v).all()]
        if empty:
            raise LogError(
                self.path, f"{what}: the column read as {empty[0]} is not numeric (or all NA)"
            )
        units = dict(self.options.units) or units_from_meta(self.meta)
        if units:
            self.meta["units"] = units
        self.meta.setdefault("source", f"R {what}")

    def _load(self) -> dict[str, Any]:
        # a missing or unreadable file: LogError naming it, before the library's import
        # (rdata brings pandas and xarray: 2.7 s of a start on the 2-core machine)
        self._read_head(16)
        rdata = require("rdata", "r", "R .rda/.rds files")
        rds = self.path.lower().endswith(RDS_ENDING)
        try:
            with warnings.catch_warnings():  # rdata warns of a file type it has to guess
                warnings.simplefilter("ignore")
                if rds:
                    return {"": rdata.read_rds(self.path)}
                return dict(rdata.read_rda(self.path))
        except Exception as exc:  # a foreign parser on any bytes: its errors are many
            kind = "saveRDS" if rds else "save"
            reason = f"{type(exc).__name__}: {exc}"
            raise LogError(self.path, f"not a readable R {kind} file ({reason})") from None

    def _choose(self, objects: dict[str, Any]) -> tuple[str, _Table]:
        tables = {k: t for k, t in ((k, _as_table(v)) for k, v in objects.items()) if t}
        wanted = self.options.variable
        if "" in objects:  # .rds: one unnamed object
            if wanted:
                raise LogError(self.path, "--variable does not apply to an .rds file (one object)")
            if "" not in tables:
                raise LogError(
                    self.path, f"holds a {_r_kind(objects[''])}, not a data.frame or matrix"
                )
            return "", tables[""]
        if wanted:
            if wanted not in objects:
                raise LogError(
                    self.path, f"no object {wanted!r} (--variable); the file has {sorted(objects)}"
                )
            if wanted not in tables:
                raise LogError(
                    self.path,
                    f"object {wanted!r} is a {_r_kind(objects[wanted])}, not a data.frame or "
                    "2-D numeric matrix",
                )
            return wanted, tables[wanted]
        if len(tables) != 1:
            listed = ", ".join(t.describe(k) for k, t in tables.items())
            others = sorted(set(objects) - set(tables))
            rest = f"; other objects: {', '.join(others)}" if others else ""
            raise LogError(
                self.path,
                f"{len(tables)} data.frames or matrices ({listed or 'none'}{rest}): choose one "
                "with --variable NAME",
            )
        return next(iter(tables.items()))

    def _where(self, index: int) -> str:
        return f"{self.variable or 'object'} row {index + 1}"


def _r_kind(obj: Any) -> str:
    """A short name of what an R object became in Python, for error messages."""
    if isinstance(obj, np.ndarray):
        return "vector" if obj.ndim == 1 else f"{obj.ndim}-D {obj.dtype} array"
    return type(obj).__name__
