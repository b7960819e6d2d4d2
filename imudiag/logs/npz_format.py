"""NPZ logs (``.npz``): streaming reader and writer.

1-D arrays named like the columns, plus an optional ``meta`` array holding a
JSON object; other arrays are ignored. Read as a stream straight from the zip
members (stored or deflated), never loading a whole array.
"""

from __future__ import annotations

import json
import lzma
import os
import shutil
import tempfile
import tokenize
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from ..samples import SampleBlock
from .base import (
    DEFAULT_BLOCK_SIZE,
    OPTIONAL_COLUMNS,
    REQUIRED_COLUMNS,
    LogError,
    LogReader,
    LogWriter,
    first_violation,
    make_block,
)

#: What zipfile and its decompressors raise on a damaged archive (found by fuzz/).
_ZIP_ERRORS = (
    zipfile.BadZipFile,
    zlib.error,
    EOFError,
    NotImplementedError,
    RuntimeError,
    ValueError,
    OSError,
    lzma.LZMAError,
)


#: Each array's header (shape, dtype, the offset of its data in its zip member, bytes) by
#: file (path, size, modification time) and member (name, CRC-32, size, place in the
#: archive): a fleet task opens a log twice (its first sample, then the diagnosis), and each
#: opening parsed every header again (numpy's header parser, ``ast.literal_eval``, was a
#: twentieth of a short log's CPU).
_HEADERS: dict[tuple[Any, ...], tuple[tuple[int, ...], np.dtype, int]] = {}
_HEADERS_KEPT = 256


class NpzReader(LogReader):
    """Streaming reader of ``.npz`` logs: reads each array's zip member in blocks."""

    format = ".npz"

    def __init__(self, path: str | Path, block_size: int = DEFAULT_BLOCK_SIZE) -> None:
        super().__init__(path, block_size)
        zf = self._zip()
        try:
            members = {n[:-4]: n for n in zf.namelist() if n.endswith(".npy")}
            for name in REQUIRED_COLUMNS:
                if name not in members:
                    raise LogError(self.path, f"missing array {name!r}")
            self._used = [n for n in REQUIRED_COLUMNS + OPTIONAL_COLUMNS if n in members]
            self._members = {n: members[n] for n in self._used}
            self.length = -1  #: samples in the log
            try:
                st = os.stat(self.path)
                self._file_key: tuple[str, int, int] | None = (
                    os.path.abspath(self.path),
                    st.st_size,
                    st.st_mtime_ns,
                )
            except OSError:
                self._file_key = None
            for name in self._used:
                shape, dtype, _offset = self._member_header(zf, name)
                if self.length < 0:
                    self.length = shape[0]
                elif shape[0] != self.length:
                    raise LogError(
                        self.path, f"array {name!r} has {shape[0]} values, 't' has {self.length}"
                    )
            if "meta" in members:
                self.meta = self._read_meta(zf, members["meta"])
        except LogError:
            raise
        except _ZIP_ERRORS as exc:
            raise LogError(self.path, f"corrupt zip data: {exc}") from None
        finally:
            self._release(zf)

    def _total_samples(self) -> int | None:
        return self.length if self.length >= 0 else None

    def _zip(self) -> zipfile.ZipFile:
        try:
            return self._open(zipfile.ZipFile, self.path)
        except LogError:
            raise
        except _ZIP_ERRORS as exc:
            raise LogError(self.path, f"not an NPZ (zip) file: {exc}") from None

    def _member_header(
        self, zf: zipfile.ZipFile, name: str
    ) -> tuple[tuple[int, ...], np.dtype, int]:
        """(shape, dtype, offset of the data in the member, bytes) of array ``name``, parsed
        once per file version (:data:`_HEADERS`)."""
        info = zf.getinfo(self._members[name])  # the member's CRC-32 covers its header
        key = (
            None
            if self._file_key is None
            else (*self._file_key, name, info.CRC, info.file_size, info.header_offset)
        )
        if key is not None and key in _HEADERS:
            return _HEADERS[key]
        with zf.open(self._members[name]) as fp:
            shape, dtype = self._header(fp, name)
            out = (shape, dtype, fp.tell())
        if key is not None:
            if len(_HEADERS) >= _HEADERS_KEPT:
                _HEADERS.clear()
            _HEADERS[key] = out
        return out

    def _header(self, fp: IO[bytes], name: str) -> tuple[tuple[int, ...], np.dtype]:
        fmt = np.lib.format
        try:
            major, minor = fmt.read_magic(fp)
            reader = {1: fmt.read_array_header_1_0, 2: fmt.read_array_header_2_0}[major]
            shape, fortran, dtype = reader(fp)
        except (ValueError, KeyError, SyntaxError, tokenize.TokenError) as exc:  # fuzz/
            reason = f"array {name!r}: not a readable .npy header: {exc}"
            raise LogError(self.path, reason) from None
        if len(shape) != 1:
            raise LogError(self.path, f"array {name!r} must be 1-D, has shape {shape}")
        if dtype.kind not in "biuf":
            raise LogError(self.path, f"array {name!r} is not numeric (dtype {dtype})")
        return shape, dtype

    def _read_meta(self, zf: zipfile.ZipFile, member: str) -> dict[str, Any]:
        try:
            with zf.open(member) as fp:
                arr = np.lib.format.read_array(fp, allow_pickle=False)
            text = arr.item() if arr.size == 1 else None
            if isinstance(text, bytes):
                text = text.decode("utf-8")
            meta = json.loads(text) if isinstance(text, str) else None
        except (ValueError, UnicodeDecodeError):
            meta = None
        if not isinstance(meta, dict):
            raise LogError(self.path, "array 'meta' is not a JSON object")
        return meta

    def _blocks(self) -> Iterator[SampleBlock]:
        zf = self._zip()
        try:
            streams = {}
            dtypes = {}
            for name in self._used:
                streams[name] = zf.open(self._members[name])
                _, dtypes[name], offset = self._member_header(zf, name)
                if len(streams[name].read(offset)) != offset:  # past the header, parsed once
                    raise LogError(self.path, f"array {name!r} is truncated")
            last_t: float | None = None
            start = 0
            while start < self.length:
                n = min(self.block_size, self.length - start)
                cols = {}
                for name in self._used:
                    nbytes = n * dtypes[name].itemsize
                    data = streams[name].read(nbytes)
                    if len(data) != nbytes:
                        raise LogError(self.path, f"array {name!r} is truncated")
                    cols[name] = np.frombuffer(data, dtype=dtypes[name]).astype(float)
                bad = first_violation(cols, last_t)
                if bad is not None:
                    raise LogError(self.path, f"sample {start + bad[0]}: {bad[1]}")
                last_t = float(cols["t"][-1])
                start += n
                yield make_block(cols, self.meta)
        except LogError:
            raise
        except _ZIP_ERRORS as exc:
            raise LogError(self.path, f"corrupt zip data: {exc}") from None
        finally:
            self._release(zf)


class NpzWriter(LogWriter):
    """Writes ``.npz`` (as ``numpy.savez``), streaming each column through a temporary file."""

    def __init__(self, path: str | Path, meta: dict[str, Any] | None = None) -> None:
        super().__init__(path, meta)
        try:
            self._meta_json = json.dumps(self.meta)
        except (TypeError, ValueError) as exc:
            raise LogError(self.path, f"metadata is not JSON serialisable: {exc}") from None
        self._tmp: dict[str, IO[bytes]] = {}
        self._dtypes: dict[str, np.dtype] = {}

    def _start(self, columns: list[str]) -> None:
        for name in columns:
            self._dtypes[name] = np.dtype(
                {"seq": np.int64, "flags": np.uint16}.get(name, np.float64)
            )
            self._tmp[name] = tempfile.TemporaryFile(dir=os.path.dirname(self._part) or ".")

    def _write(self, cols: dict[str, np.ndarray], n: int) -> None:
        for name, v in cols.items():
            self._tmp[name].write(np.ascontiguousarray(v, dtype=self._dtypes[name]).tobytes())

    def _finish(self) -> None:
        try:
            if not self._closed:
                self._assemble()
        finally:
            for fh in self._tmp.values():
                fh.close()

    def _assemble(self) -> None:
        try:
            zf = zipfile.ZipFile(self._part, "w", zipfile.ZIP_STORED, allowZip64=True)
        except OSError as exc:
            raise LogError(self.path, f"cannot write: {exc.strerror or exc}") from None
        with zf:
            for name, fh in self._tmp.items():
                with zf.open(name + ".npy", "w", force_zip64=True) as out:
                    header = {
                        "descr": np.lib.format.dtype_to_descr(self._dtypes[name]),
                        "fortran_order": False,
                        "shape": (self.samples_written,),
                    }
                    np.lib.format.write_array_header_1_0(out, header)
                    fh.seek(0)
                    shutil.copyfileobj(fh, out, 1 << 20)
            with zf.open("meta.npy", "w") as out:
                np.lib.format.write_array(out, np.array(self._meta_json), allow_pickle=False)
