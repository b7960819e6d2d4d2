"""Status over a serial line as NMEA 0183-style proprietary sentences.

Every sentence is ``$`` + address + ``,``-separated fields + ``*`` + checksum
+ CR LF, at most 82 characters in all (NMEA 0183). The checksum is the XOR of
every character between ``$`` and ``*``, written as two upper-case hex digits.
The address is the proprietary talker ``P``, the manufacturer mnemonic ``IMD``
and one letter for the sentence (docs/service.md has the full table):

``$PIMDH,t,state,n_faults,gyro_f0,accel_f0*hh``  health, every period
    ``t`` sample time, s (2 decimals; empty before the first sample);
    ``state`` ``ok | degraded | fault | no_data``; ``n_faults`` active faults;
    ``gyro_f0`` / ``accel_f0`` fraction of F0 checks failed since start
    (6 decimals; empty when the status has no ``f0`` figures).
``$PIMDF,t,k,n,triad,sensor,cause,estimate*hh``  one per active fault
    fault ``k`` of ``n`` (1-based); ``sensor`` empty where it cannot be told;
    ``estimate`` in the certificate's units for the cause (empty if none).
``$PIMDC,t,bytes,frames,crc_errors,skipped_bytes,lost,duplicates*hh``  counters
    receiver counters of spec/wire-protocol.md, each modulo 10^9 (take
    differences modulo 10^9), so that the sentence fits in 82 characters.

A status update is the cycle H, F x n, C with the same ``t``. The status dict
is the one of the stdout JSON stream (spec/reports.md): ``t``, ``state``,
``faults`` [{triad, sensor, cause[, estimate]}], ``counters`` {...}, and
optionally ``f0`` {triad: {checked, failed}} as in the diagnosis report.

:class:`SerialStatusSink` writes the cycle to a pyserial URL at a set rate and
at once on a change, from a writer thread behind a bounded queue, so a slow or
stuck receiver never blocks the caller: sentences that do not fit are dropped
and counted.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs, urlsplit

import serial

from imudiag.errors import BadInput, SinkError
from imudiag.service.status import signature

log = logging.getLogger(__name__)

TALKER = "PIMD"  #: proprietary talker P + manufacturer mnemonic IMD
HEALTH = TALKER + "H"
FAULT = TALKER + "F"
COUNTERS = TALKER + "C"
MAX_SENTENCE_CHARS = 82  #: including ``$`` and the closing CR LF (NMEA 0183)
COUNTER_MODULUS = 10**9  #: counters are sent modulo this (9 digits)
COUNTER_KEYS = ("bytes", "frames", "crc_errors", "skipped_bytes", "lost", "duplicates")
STATES = ("ok", "degraded", "fault", "no_data")
_RESERVED = set("$!*,\\^~\r\n")


class NmeaError(BadInput):
    """A sentence that breaks the format (checksum, length, characters, fields)."""


# ---------------------------------------------------------------------------
# building sentences


def checksum(body: str) -> int:
    """XOR of the character codes of ``body`` (the text between ``$`` and ``*``)."""
    value = 0
    for byte in body.encode("ascii"):
        value ^= byte
    return value


def _field(value: Any) -> str:
    text = "" if value is None else str(value)
    if any(c in _RESERVED or not (32 <= ord(c) < 127) for c in text):
        raise NmeaError(f"field {text!r} holds a reserved or non-printable character")
    return text


def sentence(address: str, fields: Sequence[Any]) -> str:
    """``$address,f1,f2,...*hh\\r\\n``; raises NmeaError past 82 characters or on bad characters."""
    body = ",".join([_field(address), *(_field(f) for f in fields)])
    text = f"${body}*{checksum(body):02X}\r\n"
    if len(text) > MAX_SENTENCE_CHARS:
        raise NmeaError(f"{address} sentence is {len(text)} characters, over {MAX_SENTENCE_CHARS}")
    return text


def _time_field(t: Any) -> str:
    if t is None:
        return ""
    t = float(t)
    return f"{t:.2f}" if math.isfinite(t) else ""


def _number_field(x: Any) -> str:
    if x is None:
        return ""
    x = float(x)
    return f"{x:.6g}" if math.isfinite(x) else ""


def _f0_ratio(status: Mapping[str, Any], triad: str) -> str:
    f0 = status.get("f0") or {}
    entry = f0.get(triad) if isinstance(f0, Mapping) else None
    if not entry or not entry.get("checked"):
        return ""
    return f"{entry.get('failed', 0) / entry['checked']:.6f}"


def health_sentence(status: Mapping[str, Any]) -> str:
    """The ``$PIMDH`` health sentence of a status dict."""
    faults = status.get("faults") or []
    return sentence(
        HEALTH,
        [
            _time_field(status.get("t")),
            status.get("state", ""),
            len(faults),
            _f0_ratio(status, "gyro"),
            _f0_ratio(status, "accel"),
        ],
    )


def fault_sentences(status: Mapping[str, Any]) -> list[str]:
    """One ``$PIMDF`` sentence per active fault (none when there is no fault)."""
    faults = status.get("faults") or []
    t = _time_field(status.get("t"))
    n = len(faults)
    return [
        sentence(
            FAULT,
            [
                t,
                k,
                n,
                f.get("triad"),
                f.get("sensor"),
                f.get("cause"),
                _number_field(f.get("estimate")),
            ],
        )
        for k, f in enumerate(faults, start=1)
    ]


def counters_sentence(status: Mapping[str, Any]) -> str:
    """The ``$PIMDC`` counters sentence (each counter modulo 10^9)."""
    counters = status.get("counters") or {}
    values = [
        "" if counters.get(k) is None else int(counters[k]) % COUNTER_MODULUS for k in COUNTER_KEYS
    ]
    return sentence(COUNTERS, [_time_field(status.get("t")), *values])


def status_sentences(status: Mapping[str, Any]) -> list[str]:
    """The full cycle for one status update: H, F x n_faults, C."""
    return [health_sentence(status), *fault_sentences(status), counters_sentence(status)]


# ---------------------------------------------------------------------------
# parsing


@dataclass(frozen=True)
class Sentence:
    """A parsed sentence: ``address`` such as ``PIMDH`` and its text ``fields``."""

    address: str
    fields: tuple[str, ...]


def parse_sentence(line: str | bytes) -> Sentence:
    """Check framing, length, characters and checksum of one sentence and split it.

    ``line`` may end in CR LF (a bare line without it is accepted too, as read
    by ``readline().strip()``); raises :class:`NmeaError` naming the problem.
    """
    if isinstance(line, bytes):
        try:
            line = line.decode("ascii")
        except UnicodeDecodeError:
            raise NmeaError(f"non-ASCII bytes in {line!r}") from None
    full = line if line.endswith("\r\n") else line.rstrip("\r\n") + "\r\n"
    if len(full) > MAX_SENTENCE_CHARS:
        raise NmeaError(f"{len(full)} characters, over {MAX_SENTENCE_CHARS}: {line!r}")
    text = full[:-2]
    if not text.startswith("$"):
        raise NmeaError(f"does not start with '$': {line!r}")
    if len(text) < 4 or text[-3] != "*":
        raise NmeaError(f"no '*hh' checksum at the end: {line!r}")
    body, given = text[1:-3], text[-2:]
    if any(not (32 <= ord(c) < 127) or c in "$*\r\n" for c in body):
        raise NmeaError(f"reserved or non-printable character in {line!r}")
    try:
        given_value = int(given, 16)
    except ValueError:
        raise NmeaError(f"checksum {given!r} is not two hex digits: {line!r}") from None
    if given_value != checksum(body):
        raise NmeaError(
            f"checksum mismatch: sentence says {given}, body gives {checksum(body):02X}: {line!r}"
        )
    address, *fields = body.split(",")
    return Sentence(address, tuple(fields))


def split_sentences(buffer: bytes) -> tuple[list[str], bytes]:
    """Cut a received byte stream into candidate sentences, as a receiver does.

    Each candidate runs from the last ``$`` before a CR LF up to that CR LF
    (a sentence cut short by a write timeout is skipped: the receiver
    resynchronises on the next ``$``). Returns the candidates as text, without
    CR LF and not yet validated (use :func:`parse_sentence`), and the
    unterminated rest of ``buffer`` to prepend to the next read.
    """
    *lines, rest = buffer.split(b"\r\n")
    out = []
    for raw in lines:
        start = raw.rfind(b"$")
        if start >= 0:
            out.append(raw[start:].decode("ascii", errors="replace"))
    return out, rest


def _opt_float(text: str, what: str) -> float | None:
    if text == "":
        return None
    try:
        return float(text)
    except ValueError:
        raise NmeaError(f"{what}: not a number: {text!r}") from None


def _int(text: str, what: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise NmeaError(f"{what}: not an integer: {text!r}") from None


def decode_sentence(line: str | bytes) -> dict[str, Any]:
    """Parse and interpret one imudiag sentence as a dict with ``type`` health/fault/counters."""
    s = parse_sentence(line)
    f = s.fields
    expected = {HEALTH: 5, FAULT: 7, COUNTERS: 7}
    if s.address not in expected:
        raise NmeaError(f"unknown sentence {s.address!r} (known: {', '.join(expected)})")
    if len(f) != expected[s.address]:
        raise NmeaError(f"{s.address}: expected {expected[s.address]} fields, got {len(f)}")
    t = _opt_float(f[0], f"{s.address} t")
    if s.address == HEALTH:
        if f[1] not in STATES:
            raise NmeaError(f"{HEALTH}: unknown state {f[1]!r}")
        return {
            "type": "health",
            "t": t,
            "state": f[1],
            "n_faults": _int(f[2], f"{HEALTH} n_faults"),
            "f0_failed_ratio": {
                "gyro": _opt_float(f[3], f"{HEALTH} gyro_f0"),
                "accel": _opt_float(f[4], f"{HEALTH} accel_f0"),
            },
        }
    if s.address == FAULT:
        return {
            "type": "fault",
            "t": t,
            "index": _int(f[1], f"{FAULT} k"),
            "count": _int(f[2], f"{FAULT} n"),
            "triad": f[3],
            "sensor": f[4] or None,
            "cause": f[5],
            "estimate": _opt_float(f[6], f"{FAULT} estimate"),
        }
    counters = {
        k: (None if v == "" else _int(v, f"{COUNTERS} {k}"))
        for k, v in zip(COUNTER_KEYS, f[1:], strict=True)
    }
    return {"type": "counters", "t": t, "counters": counters}


# ---------------------------------------------------------------------------
# the serial sink


class StatusLinkError(SinkError):
    """The status serial port cannot be opened (the message names the URL)."""


def open_status_port(url: str, write_timeout_s: float = 0.5) -> serial.SerialBase:
    """Open a status link: a pyserial URL (``loop://``, ``socket://host:port``, a
    device path such as ``/dev/ttyS1``) or ``serial:///dev/ttyS1?baud=115200``."""
    target = url
    kwargs: dict[str, Any] = {}
    parts = urlsplit(url)
    if parts.scheme == "serial":
        target = parts.netloc + parts.path
        params = {k: v[-1] for k, v in parse_qs(parts.query).items()}
        if "baud" in params:
            try:
                kwargs["baudrate"] = int(params["baud"])
            except ValueError:
                raise StatusLinkError(f"{url}: bad baud rate {params['baud']!r}") from None
    try:
        return serial.serial_for_url(target, write_timeout=write_timeout_s, **kwargs)
    except (serial.SerialException, ValueError, OSError) as exc:
        raise StatusLinkError(f"status link {url}: cannot open: {exc}") from None


def _change_key(status: Mapping[str, Any]) -> tuple[Any, ...]:
    return signature(status.get("state") or "", status.get("faults") or [])


class SerialStatusSink:
    """Writes status as NMEA sentences to a serial URL without ever blocking the caller.

    :meth:`publish` may be called on every pass of the daemon loop: it emits a
    cycle (H, F x n, C) when ``1 / rate_hz`` seconds have passed since the last
    one or at once when ``state`` or the set of faults changed. Sentences go
    into a queue of ``queue_size`` sentences drained by a writer thread; when
    the queue is full the oldest sentence is dropped (the newest status wins)
    and counted in :attr:`dropped`, as are sentences whose write timed out after
    ``write_timeout_s`` seconds. If the port fails (an unplugged USB adapter)
    the writer reopens it every ``reopen_s`` seconds, dropping meanwhile.
    """

    def __init__(
        self,
        url: str,
        rate_hz: float = 1.0,
        queue_size: int = 64,
        write_timeout_s: float = 0.5,
        reopen_s: float = 1.0,
    ) -> None:
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz!r}")
        if queue_size < 1:
            raise ValueError(f"queue_size must be >= 1, got {queue_size!r}")
        self.url = url
        self.rate_hz = float(rate_hz)
        self.write_timeout_s = float(write_timeout_s)
        self.reopen_s = float(reopen_s)
        self.dropped = 0  #: sentences dropped (queue full, write timeout, port down)
        self.written = 0  #: sentences written completely
        self.errors = 0  #: port failures (each followed by a reopen attempt)
        self.cycles = 0  #: status cycles queued
        self._port: serial.SerialBase | None = open_status_port(url, self.write_timeout_s)
        self._queue: queue.Queue[str | None] = queue.Queue(maxsize=queue_size)
        self._count_lock = threading.Lock()
        self._stop = threading.Event()
        self._abort = threading.Event()
        self._last_emit_s: float | None = None
        self._last_key: tuple | None = None
        self._thread = threading.Thread(target=self._run, name="nmea-status", daemon=True)
        self._thread.start()

    # -- caller side (never blocks) -------------------------------------------

    @property
    def port(self) -> serial.SerialBase | None:
        """The open pyserial port (for ``loop://`` the same object reads back what was sent)."""
        return self._port

    @property
    def pending(self) -> int:
        """Sentences waiting in the queue."""
        return self._queue.qsize()

    def wants(self, key: tuple[Any, ...], now_s: float) -> bool:
        """Whether :meth:`publish` would queue a cycle now for a status whose state and
        fault identities are ``key`` (:func:`imudiag.service.status.signature`): the
        daemon builds a status for this sink only then."""
        due = self._last_emit_s is None or now_s - self._last_emit_s >= 1.0 / self.rate_hz
        return due or key != self._last_key

    def publish(self, status: Mapping[str, Any], now_s: float | None = None) -> bool:
        """Queue a cycle for ``status`` if one is due or the state/faults changed.

        ``now_s`` is a monotonic clock in seconds (default ``time.monotonic()``).
        Returns True when a cycle was queued (possibly dropping older sentences).
        """
        now_s = time.monotonic() if now_s is None else now_s
        key = _change_key(status)
        if not self.wants(key, now_s):
            return False
        try:
            lines = status_sentences(status)
        except (NmeaError, TypeError, ValueError) as exc:
            log.warning("status not representable as NMEA: %s", exc)
            return False
        self._last_emit_s = now_s
        self._last_key = key
        self.cycles += 1
        for line in lines:
            self._enqueue(line)
        return True

    def _enqueue(self, line: str) -> None:
        while True:
            try:
                self._queue.put_nowait(line)
                return
            except queue.Full:
                try:
                    old = self._queue.get_nowait()
                except queue.Empty:
                    continue
                if old is None:  # the stop sentinel stays in front
                    self._queue.put_nowait(None)
                    return
                self._count_drop()

    def _count_drop(self, n: int = 1) -> None:
        with self._count_lock:
            self.dropped += n

    # -- writer thread ----------------------------------------------------------

    def _run(self) -> None:
        next_reopen = 0.0
        while True:
            line = self._queue.get()
            if line is None:
                return
            if self._abort.is_set():
                self._count_drop()
                continue
            if self._port is None:
                if time.monotonic() >= next_reopen:
                    try:
                        self._port = open_status_port(self.url, self.write_timeout_s)
                        log.info("status link %s reopened", self.url)
                    except StatusLinkError as exc:
                        log.debug("%s", exc)
                        next_reopen = time.monotonic() + self.reopen_s
                if self._port is None:
                    self._count_drop()
                    continue
            try:
                self._port.write(line.encode("ascii"))
                self.written += 1
            except serial.SerialTimeoutException:
                self._count_drop()  # receiver not keeping up
            except queue.Full:
                self._count_drop()  # loop:// buffer full (pyserial raises queue.Full there)
            except (serial.SerialException, OSError) as exc:
                self._count_drop()
                self.errors += 1
                log.warning("status link %s failed: %s; reopening", self.url, exc)
                try:
                    self._port.close()
                except (serial.SerialException, OSError):
                    pass
                self._port = None
                next_reopen = time.monotonic() + self.reopen_s

    # -- lifetime -------------------------------------------------------------

    def close(self, timeout_s: float = 1.0) -> None:
        """Stop the writer (after at most ``timeout_s`` s of draining) and close the port."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._enqueue(None)  # type: ignore[arg-type]
        self._thread.join(timeout_s)
        if self._thread.is_alive():  # the receiver is not reading: give up on the rest
            self._abort.set()
            port = self._port
            if port is not None:
                # unblock a write stuck on a full buffer: serial ports cancel it; pyserial's
                # socket:// handler has no cancel_write, and closing the socket does it
                cancel = getattr(port, "cancel_write", None)
                try:
                    if callable(cancel):
                        cancel()
                    else:
                        port.close()
                except (serial.SerialException, OSError):
                    pass
            self._thread.join(timeout_s + self.write_timeout_s)
        if self._port is not None:
            try:
                self._port.close()
            except (serial.SerialException, OSError):
                pass
        # sentences never written count as dropped
        leftover = 0
        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                break
            if item is not None:
                leftover += 1
        self._count_drop(leftover)

    def __enter__(self) -> SerialStatusSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = [
    "COUNTERS",
    "COUNTER_KEYS",
    "FAULT",
    "HEALTH",
    "MAX_SENTENCE_CHARS",
    "NmeaError",
    "SerialStatusSink",
    "Sentence",
    "StatusLinkError",
    "checksum",
    "counters_sentence",
    "decode_sentence",
    "fault_sentences",
    "health_sentence",
    "open_status_port",
    "parse_sentence",
    "sentence",
    "split_sentences",
    "status_sentences",
]
