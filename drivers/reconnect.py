"""ReconnectingSource: survive a device being unplugged and plugged back in.

Wraps the source of any URL. When the transport raises SourceError (device
gone, port closed) the wrapper closes it, reports ``state == "reconnecting"``
and retries opening with exponential back-off between ``min_backoff_s`` and
``max_backoff_s`` seconds; once open again it reports ``"connected"`` and
counts the reconnect. The same inner source object is reopened, so its
counters (and the decoder's seq/time state: frames missed while unplugged
count as lost, a board restart re-anchors the timeline) carry across.
"""

from __future__ import annotations

import time
from typing import Any

from imudiag.samples import SampleBlock

from .base import Source, SourceError, open_source, parse_url

CONNECTED = "connected"
RECONNECTING = "reconnecting"


class ReconnectingSource(Source):
    """A source that reopens its inner source after SourceError, with back-off.

    ``state`` is ``"connected"`` or ``"reconnecting"``; ``reconnects`` counts
    successful reopenings after a loss; ``last_error`` is the message of the
    latest failure. :meth:`open` does not fail when the device is absent: the
    source starts in ``"reconnecting"`` (a daemon may start before the board
    is plugged in). EndOfStream from a finite inner source passes through.
    """

    def __init__(
        self,
        url: str,
        min_backoff_s: float = 0.1,
        max_backoff_s: float = 5.0,
        **options: Any,
    ) -> None:
        if not 0 < min_backoff_s <= max_backoff_s:
            raise ValueError(
                f"back-off: need 0 < min_backoff_s <= max_backoff_s, got {min_backoff_s}, "
                f"{max_backoff_s}"
            )
        super().__init__(parse_url(url), **options)
        self.inner: Source = open_source(url, **options)
        self.counters = self.inner.counters
        self.min_backoff_s = min_backoff_s
        self.max_backoff_s = max_backoff_s
        self.state = RECONNECTING
        self.reconnects = 0
        self.attempts = 0  #: failed open attempts since the last loss
        self.last_error: str | None = None
        self._backoff_s = min_backoff_s
        self._next_attempt = 0.0
        self._ever_connected = False
        self._opened = False

    @property
    def backoff_s(self) -> float:
        """The wait, seconds, before the next open attempt after a failed one."""
        return self._backoff_s

    @property
    def device_info(self) -> dict[str, Any]:
        """The inner source's latest device information."""
        return self.inner.device_info

    @device_info.setter
    def device_info(self, value: dict[str, Any]) -> None:
        pass  # owned by the inner source

    def open(self) -> None:
        """Try to open now; on failure stay ``"reconnecting"`` and retry on later reads."""
        self._opened = True
        if self.state != CONNECTED:
            self._try_open(time.monotonic())

    def _try_open(self, now: float) -> bool:
        try:
            self.inner.open()
        except SourceError as e:
            self.last_error = str(e)
            if self.attempts:
                self._backoff_s = min(self._backoff_s * 2.0, self.max_backoff_s)
            self.attempts += 1
            self._next_attempt = now + self._backoff_s
            return False
        if self._ever_connected:
            self.reconnects += 1
        self._ever_connected = True
        self.state = CONNECTED
        self.attempts = 0
        self._backoff_s = self.min_backoff_s
        return True

    def _lost(self, error: SourceError, now: float) -> None:
        self.last_error = str(error)
        self.inner.close()
        self.state = RECONNECTING
        self._backoff_s = self.min_backoff_s
        self._next_attempt = now + self._backoff_s

    def read(self, timeout_s: float = 0.1) -> SampleBlock:
        """Samples within ``timeout_s`` seconds; while reconnecting, an empty block."""
        if not self._opened:
            raise SourceError(f"{self.url.url}: read on a source that is not open")
        deadline = time.monotonic() + timeout_s
        remaining = timeout_s  # the same value each turn while connected: a serial port
        if self.state == RECONNECTING:  # is not reconfigured (tcsetattr) on every read
            now = time.monotonic()
            if now < self._next_attempt:
                time.sleep(max(0.0, min(self._next_attempt, deadline) - now))
                if time.monotonic() < self._next_attempt:
                    return SampleBlock.empty()
            if not self._try_open(time.monotonic()):
                return SampleBlock.empty()
            remaining = max(0.0, deadline - time.monotonic())
        try:
            return self.inner.read(remaining)
        except SourceError as e:
            self._lost(e, time.monotonic())
            return SampleBlock.empty()

    def write_command(self, line: str) -> None:
        """Forward a command while connected; dropped while reconnecting."""
        if self.state != CONNECTED:
            return
        try:
            self.inner.write_command(line)
        except SourceError as e:
            self._lost(e, time.monotonic())

    def close(self) -> None:
        """Close the inner source; safe to call twice."""
        self._opened = False
        self.inner.close()
