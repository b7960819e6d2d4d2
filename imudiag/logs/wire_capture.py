"""Raw wire captures (``.bin``): the byte stream of spec/wire-protocol.md.

Decoded by :class:`imudiag.drivers.wire.Decoder`; ``t`` is the device clock,
outputs are integer ADC counts, the latest device-info frame is the metadata.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..samples import SampleBlock
from .base import (
    DEFAULT_BLOCK_SIZE,
    REQUIRED_COLUMNS,
    LogError,
    LogReader,
    LogWriter,
    first_violation,
)

#: Device-info key saying the capture has no temperature (its frames' temp field is 0).
NO_TEMP_KEY = "temperature"


class BinReader(LogReader):
    """Reader of raw wire captures (``.bin``) through the live frame decoder.

    ``t`` is the unwrapped device clock (s); ``counters`` are the decoder's
    receiver counters (CRC errors, lost frames...) of the bytes read so far;
    ``meta`` is the latest device-info frame seen when the log was opened.
    """

    format = ".bin"

    def __init__(self, path: str | Path, block_size: int = DEFAULT_BLOCK_SIZE) -> None:
        super().__init__(path, block_size)
        from ..drivers.wire import SAMPLE_FRAME_SIZE

        self._chunk = self.block_size * SAMPLE_FRAME_SIZE
        decoder = self._decoder()
        fh = self._open(open, self.path, "rb")
        try:
            decoder.feed(fh.read(self._chunk))
        finally:
            self._release(fh)
        self.meta = dict(decoder.device_info)
        #: False when the writer said the capture has no temperature (temp then None)
        self.has_temp = self.meta.pop(NO_TEMP_KEY, True) is not False
        self.counters = decoder.counters

    @staticmethod
    def _decoder() -> Any:
        from ..drivers.wire import Decoder

        return Decoder()

    def _blocks(self) -> Iterator[SampleBlock]:
        decoder = self._decoder()
        self.counters = decoder.counters
        fh = self._open(open, self.path, "rb")
        try:
            last_t: float | None = None
            done = 0
            while True:
                data = fh.read(self._chunk)
                block = decoder.feed(data) if data else decoder.finish()
                if decoder.device_info:
                    info = dict(decoder.device_info)
                    self.has_temp = info.pop(NO_TEMP_KEY, True) is not False
                    self.meta.update(info)
                if len(block):
                    bad = first_violation({"t": block.t}, last_t)
                    if bad is not None:
                        seq = "" if block.seq is None else f" (frame seq {block.seq[bad[0]]})"
                        raise LogError(self.path, f"sample {done + bad[0]}{seq}: {bad[1]}")
                    last_t = float(block.t[-1])
                    done += len(block)
                    block.meta = self.meta
                    if not self.has_temp:
                        block.temp = None  # the writer said the log had no temperature
                    for start in range(0, len(block), self.block_size):
                        yield block.slice(start, start + self.block_size)
                if not data:
                    return
        finally:
            self._release(fh)


class BinWriter(LogWriter):
    """Writes raw wire captures (``.bin``) with :func:`imudiag.drivers.wire.encode_samples`.

    Outputs are rounded to int32 counts, ``t`` (s) to whole microseconds of the
    device clock (wrapping as the spec says), temp to 0.01 degC. The metadata,
    if any, is written first as a device-info frame (its JSON must fit the
    frame: at most 249 bytes), with the seq just before the first sample's.
    ``seq`` is taken from the blocks when present (gaps kept; it reads back
    from the first sample's 16-bit value, unwrapped), otherwise counted from 1.
    The decoder always yields flags (0 where the blocks had none). Blocks without
    temperature are written with ``"temperature": false`` in the device-info
    frame and read back without temperature (the frames' temp field is 0).
    """

    def __init__(self, path: str | Path, meta: dict[str, Any] | None = None) -> None:
        super().__init__(path, meta)
        from ..drivers import wire

        self._wire = wire
        self._info: bytes | None = None
        if self.meta:
            text = json.dumps(self.meta, separators=(",", ":")).encode("utf-8")
            if len(text) > 249:
                raise LogError(
                    self.path,
                    f"metadata is {len(text)} bytes of JSON, a device-info frame holds 249",
                )
        try:
            self._fh = open(self._part, "wb")  # noqa: SIM115 - closed in _finish
        except OSError as exc:
            raise LogError(self.path, f"cannot write: {exc.strerror or exc}") from None
        self._seq = 1

    def _write(self, cols: dict[str, np.ndarray], n: int) -> None:
        if cols["t"][0] < 0:
            raise LogError(self.path, "t must be >= 0 s in a .bin capture (device clock)")
        time_us = np.rint(cols["t"] * 1e6).astype(np.int64)
        raw = np.rint(np.column_stack([cols[c] for c in REQUIRED_COLUMNS[1:]]))
        if np.any(np.abs(raw) > 2**31 - 1):
            raise LogError(self.path, "output outside the int32 range of a .bin capture")
        raw = raw.astype(np.int32)
        seq = cols["seq"].astype(np.int64) if "seq" in cols else self._seq + np.arange(n)
        info = self.meta
        if "temp" not in cols:  # said in the device info, so it reads back as absent, not 0.0
            info = {**self.meta, NO_TEMP_KEY: False}
        if self.samples_written == 0 and info:
            size = len(json.dumps(info, separators=(",", ":")).encode("utf-8"))
            if size > 249:
                raise LogError(
                    self.path,
                    f"metadata is {size} bytes of JSON with '{NO_TEMP_KEY}': false (the log "
                    "has no temperature), a device-info frame holds 249",
                )
            self._fh.write(self._wire.encode_info(int(seq[0] - 1) & 0xFFFF, int(time_us[0]), info))
        temp, flags = cols.get("temp"), cols.get("flags")
        cuts = np.flatnonzero(np.diff(seq) != 1) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, n], strict=True):
            self._fh.write(
                self._wire.encode_samples(
                    int(seq[a]) & 0xFFFF,
                    time_us[a:b],
                    raw[a:b],
                    None if temp is None else temp[a:b],
                    None if flags is None else flags[a:b].astype(np.uint16),
                )
            )
        self._seq = int(seq[-1]) + 1

    def _finish(self) -> None:
        self._fh.close()
