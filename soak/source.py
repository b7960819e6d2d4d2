"""``soak://?hours=H&seed=N&rate=HZ&errors=X&episodes=S``: the soak stream as a byte transport.

A :class:`imudiag.drivers.bytesource.ByteSource` like the serial port, so the
daemon reads it through the same path (ReconnectingSource -> ByteSource ->
wire Decoder): chunks of random size (frames straddle reads), SourceError at
each unplug marker, EndOfStream after the last byte. Registered on import of
this module.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from imudiag.certificate import load_default
from imudiag.drivers.base import EndOfStream, SourceError, SourceURL, register
from imudiag.drivers.bytesource import ByteSource

from .stream import Injected, SoakStream, Unplug

MAX_READ_BYTES = 1 << 16  #: largest chunk handed out by one read, bytes


@register("soak")
class SoakSource(ByteSource):
    """The soak stream (see :mod:`soak.stream`) read in random-sized chunks."""

    def __init__(self, url: SourceURL, **options: Any) -> None:
        super().__init__(url, **options)
        cert = options.get("certificate") or load_default()
        hours = float(url.get("hours", 1.0, float))
        self.stream = SoakStream(
            cert,
            duration_s=hours * 3600.0,
            rate_hz=float(url.get("rate", cert.sample_rate, float)),
            seed=int(url.get("seed", 0, int)),
            error_rate=float(url.get("errors", 1.0, float)),
            episode_every_s=float(url.get("episodes", 600.0, float)) or None,
        )
        self._rng = np.random.default_rng(int(url.get("seed", 0, int)) + 1)
        self._pieces: list[bytes | Unplug] = []
        self._head = 0  # index of the next piece
        self._offset = 0  # bytes of that piece already handed out

    @property
    def injected(self) -> Injected:
        """The exact tally of what the stream injected and delivered."""
        return self.stream.injected

    def _open_transport(self) -> None:
        """Nothing to open: the stream continues where the unplug left it."""

    def _close_transport(self) -> None:
        """Nothing to release."""

    def _fill(self) -> bool:
        """Make sure a piece is pending; False at the end of the stream."""
        while self._head >= len(self._pieces):
            if self.stream.exhausted:
                return False
            self._pieces = self.stream.next_pieces()
            self._head = 0
            self._offset = 0
        return True

    def _read_bytes(self, timeout_s: float) -> bytes:
        """The next chunk (1 .. MAX_READ_BYTES bytes, never across an unplug marker)."""
        want = int(self._rng.integers(1, MAX_READ_BYTES + 1))
        out: list[bytes] = []
        got = 0
        while got < want:
            if not self._fill():
                break
            piece = self._pieces[self._head]
            if isinstance(piece, Unplug):
                if got:
                    break  # hand out what came before the unplug first
                self._head += 1
                raise SourceError(f"{self.url.url}: simulated unplug")
            take = piece[self._offset : self._offset + want - got]
            out.append(take)
            got += len(take)
            self._offset += len(take)
            if self._offset >= len(piece):
                self._head += 1
                self._offset = 0
        if not got:
            raise EndOfStream(f"{self.url.url}: end of the soak stream")
        self.stream.injected.bytes += got
        return b"".join(out)
