"""The soak's byte stream: simulated board data with transport errors and sensor faults injected,
and an exact tally of what was injected.

The board data are a simulated stretch of the static scenario (still in a few
attitudes, slow turns, one cycle 96 s), generated once and replayed
cyclically with ever increasing ``seq`` and ``time_us`` (both wrap as on the
wire), framed like the simulated board: a device-info frame at every seq that
is a multiple of 1000 and 999 sample frames between. Within each such group
of frames, events are placed at separate slots so they never interact:

- ``crc``: one payload bit flipped (never forming a sync inside the frame):
  +1 crc_errors, +40 skipped_bytes, +1 lost (its seq never arrives);
- ``drop``: 1-5 frames removed: +k lost;
- ``dup``: a frame sent twice: +1 duplicates;
- ``garbage``: 1-100 bytes (never 0xAA, so no false sync) between frames: +m skipped;
- ``unplug``: the link drops after the first q (1-39) bytes of a frame, then
  L (0-20) more frames go by unseen: the source raises SourceError; at the
  reopen the q held-back bytes are skipped: +q skipped_bytes, +1+L lost, +1 reconnect;
- ``adc``: a sample with the ADC-error flag: +1 monitor ``adc_errors`` if it arrives.

Sensor-fault episodes alternate every ``episode_every_s`` of data: a gross
accelerometer bias (+800 counts on az for 10 s: F0 must flag the accel
triad) and a stuck gyro channel (gx frozen for 3 s: the monitor must report
it stuck).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from imudiag.certificate import Certificate
from imudiag.drivers.wire import SAMPLE_FRAME_SIZE, SYNC, encode_info, encode_samples
from imudiag.samples import FLAG_ADC_ERROR
from imudiag.sim.effects import Effects
from imudiag.sim.scenarios import scenario_motion
from imudiag.sim.simulator import Simulator

GROUP_SAMPLES = 999  #: sample frames between two device-info frames
SLOT_ROWS = 25  #: frames per event slot (an unplug uses at most 22)
FIRST_SLOT_ROW = 10  #: no event in the first frames of a group
CYCLE_S = 96.0  #: one cycle of the static scenario (4 attitudes x (20 s dwell + 4 s turn))
BASE_CYCLES = 3  #: simulated cycles replayed cyclically
BIAS_EPISODE_S = 10.0  #: s
BIAS_EPISODE_COUNTS = 800.0  #: counts added to az (about 1.9 m/s^2)
STUCK_EPISODE_S = 3.0  #: s

#: Mean events per minute of data at error_rate 1.
EVENT_RATES_PER_MIN = {
    "crc": 2.0,
    "drop": 1.0,
    "dup": 1.0,
    "garbage": 1.0,
    "unplug": 0.5,
    "adc": 3.0,
}


class Unplug:
    """Marker in the byte stream: the link drops here."""


UNPLUG = Unplug()


@dataclass
class Injected:
    """What the stream injected and delivered: the counters the receiver must report."""

    bytes: int = 0  #: bytes handed to the transport reader
    frames: int = 0  #: good, non-duplicate sample frames delivered
    crc_errors: int = 0
    skipped_bytes: int = 0
    lost: int = 0
    duplicates: int = 0
    adc_errors: int = 0  #: delivered samples flagged with an ADC error
    reconnects: int = 0  #: unplug events
    events: dict[str, int] = field(default_factory=dict)  #: count per event kind

    def counters(self) -> dict[str, int]:
        """The six wire-protocol counters, as the status ``counters`` object."""
        return {
            "bytes": self.bytes,
            "frames": self.frames,
            "crc_errors": self.crc_errors,
            "skipped_bytes": self.skipped_bytes,
            "lost": self.lost,
            "duplicates": self.duplicates,
        }


@dataclass(frozen=True)
class Episode:
    """A sensor fault over sample time [t_start, t_end) s."""

    kind: str  #: "bias" (accel az) or "stuck" (gyro gx)
    t_start: float
    t_end: float

    @property
    def triad(self) -> str:
        return "accel" if self.kind == "bias" else "gyro"


class SoakStream:
    """Generates the soak's stream group by group (see the module docstring).

    ``duration_s`` of data at ``rate_hz`` (1e6 / rate_hz must be a whole number
    of microseconds); ``error_rate`` scales the event rates; ``episode_every_s``
    spaces the sensor-fault episodes (None: none).
    """

    def __init__(
        self,
        certificate: Certificate,
        duration_s: float,
        rate_hz: float = 1000.0,
        seed: int = 0,
        error_rate: float = 1.0,
        episode_every_s: float | None = 600.0,
    ) -> None:
        period_us = 1e6 / rate_hz
        if period_us != round(period_us) or period_us <= 0:
            raise ValueError(f"rate_hz must divide 1e6 us, got {rate_hz}")
        self.rate_hz = float(rate_hz)
        self.period_us = int(round(period_us))
        self.total_samples = int(round(duration_s * rate_hz))
        self.rng = np.random.default_rng(np.random.SeedSequence([seed, 7]))
        self.injected = Injected(events={k: 0 for k in EVENT_RATES_PER_MIN})
        group_min = GROUP_SAMPLES / rate_hz / 60.0
        self._p = {k: min(1.0, r * error_rate * group_min) for k, r in EVENT_RATES_PER_MIN.items()}
        self.episodes = self._episodes(duration_s, episode_every_s)
        self._base_raw, self._base_temp = self._simulate_base(certificate, seed)
        self._info = {
            "model": "soak",
            "serial": str(certificate.device.get("serial", "")),
            "fw": "soak-1",
            "rate_hz": rate_hz,
        }
        self.next_group = 0

    @property
    def groups(self) -> int:
        """Groups of frames in the whole stream."""
        return -(-self.total_samples // GROUP_SAMPLES)

    @property
    def exhausted(self) -> bool:
        """True when every group was generated."""
        return self.next_group >= self.groups

    # -- setup ----------------------------------------------------------------

    def _episodes(self, duration_s: float, every_s: float | None) -> list[Episode]:
        out: list[Episode] = []
        if not every_s:
            return out
        t = every_s
        k = 0
        while t + BIAS_EPISODE_S + 30.0 < duration_s:
            if k % 2 == 0:
                out.append(Episode("bias", t, t + BIAS_EPISODE_S))
            else:
                out.append(Episode("stuck", t, t + STUCK_EPISODE_S))
            t += every_s
            k += 1
        return out

    def _simulate_base(self, cert: Certificate, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """BASE_CYCLES cycles of the static scenario: raw counts (M, 6) int32, temp (M,) degC."""
        n = int(round(BASE_CYCLES * CYCLE_S * self.rate_hz))
        sim = Simulator(cert, Effects.board(), (), seed)
        motion = scenario_motion("static", seed)
        raw = np.empty((n, 6), dtype=np.int32)
        temp = np.empty(n)
        step = 1 << 16
        for start in range(0, n, step):
            k = min(step, n - start)
            block = sim.step(motion.sample(self.rate_hz, start, k))
            raw[start : start + k, :3] = block.gyro
            raw[start : start + k, 3:] = block.accel
            temp[start : start + k] = 25.0 if block.temp is None else block.temp
        return raw, temp

    # -- generation -------------------------------------------------------------

    def next_pieces(self) -> list[bytes | Unplug]:
        """The bytes (and unplug markers) of the next group of frames."""
        g = self.next_group
        self.next_group += 1
        k0 = g * GROUP_SAMPLES
        k = np.arange(k0, min(k0 + GROUP_SAMPLES, self.total_samples), dtype=np.int64)
        n = k.size
        idx = k % self._base_raw.shape[0]
        raw = self._base_raw[idx].astype(np.int64)
        t_s = k / self.rate_hz
        for ep in self.episodes:
            if ep.t_start < t_s[-1] + 1e-9 and ep.t_end > t_s[0]:
                sel = (t_s >= ep.t_start) & (t_s < ep.t_end)
                if ep.kind == "bias":
                    raw[sel, 5] += int(BIAS_EPISODE_COUNTS)
                else:
                    frozen = int(
                        self._base_raw[
                            int(round(ep.t_start * self.rate_hz)) % self._base_raw.shape[0], 0
                        ]
                    )
                    raw[sel, 0] = frozen
        time_us = k * self.period_us
        flags = np.zeros(n, dtype=np.int64)
        events = self._events(n)
        for row in events["adc"]:
            flags[row] |= FLAG_ADC_ERROR
            self.injected.events["adc"] += 1
        seq0 = 1000 * g
        frames = encode_samples(seq0 + 1, time_us, raw, self._base_temp[idx], flags)
        rows = np.frombuffer(frames, dtype=np.uint8).reshape(n, SAMPLE_FRAME_SIZE).copy()
        t_info = int(time_us[0] - self.period_us) if g else 0
        pieces: list[bytes | Unplug] = [encode_info(seq0, max(t_info, 0), self._info)]
        delivered = np.ones(n, dtype=bool)  # rows whose sample arrives intact
        inj = self.injected
        pos = 0  # next row not yet emitted
        for row, kind, arg in sorted(events["slots"]):
            pieces.append(rows[pos:row].tobytes())
            pos = row
            inj.events[kind] += 1
            if kind == "crc":
                pieces.append(self._corrupt(rows[row]))
                delivered[row] = False
                inj.crc_errors += 1
                inj.skipped_bytes += SAMPLE_FRAME_SIZE
                inj.lost += 1
                pos = row + 1
            elif kind == "drop":
                delivered[row : row + arg] = False
                inj.lost += arg
                pos = row + arg
            elif kind == "dup":
                pieces.append(rows[row].tobytes() * 2)
                inj.duplicates += 1
                pos = row + 1
            elif kind == "garbage":
                pieces.append(self._garbage(arg))
                inj.skipped_bytes += arg
            else:  # unplug after q bytes of this row, then `lost_after` rows unseen
                q, lost_after = arg
                pieces.append(rows[row, :q].tobytes())
                pieces.append(UNPLUG)
                delivered[row : row + 1 + lost_after] = False
                inj.skipped_bytes += q
                inj.lost += 1 + lost_after
                inj.reconnects += 1
                pos = row + 1 + lost_after
        pieces.append(rows[pos:].tobytes())
        inj.frames += int(np.count_nonzero(delivered))
        inj.adc_errors += int(np.count_nonzero(delivered & ((flags & FLAG_ADC_ERROR) != 0)))
        return pieces

    def _events(self, n: int) -> dict[str, Any]:
        """Events of one group: slot events (row, kind, argument) and ADC-flag rows."""
        rng = self.rng
        slots_free = max((n - FIRST_SLOT_ROW - SLOT_ROWS) // SLOT_ROWS, 0)
        kinds = [
            k for k in ("crc", "drop", "dup", "garbage", "unplug") if rng.random() < self._p[k]
        ]
        chosen = rng.permutation(slots_free)[: len(kinds)] if slots_free else []
        out: list[tuple[int, str, Any]] = []
        for kind, slot in zip(kinds, chosen, strict=False):
            row = FIRST_SLOT_ROW + int(slot) * SLOT_ROWS
            if kind == "drop":
                arg: Any = int(rng.integers(1, 6))
            elif kind == "garbage":
                arg = int(rng.integers(1, 101))
            elif kind == "unplug":
                arg = (int(rng.integers(1, SAMPLE_FRAME_SIZE)), int(rng.integers(0, 21)))
            else:
                arg = None
            out.append((row, kind, arg))
        adc = []
        if n > 1 and rng.random() < self._p["adc"]:
            adc.append(int(rng.integers(0, n)))
        return {"slots": out, "adc": adc}

    def _corrupt(self, frame: np.ndarray) -> bytes:
        """The frame with one payload bit flipped, never with a sync inside it."""
        for _ in range(100):
            bad = frame.copy()
            bad[int(self.rng.integers(10, 38))] ^= np.uint8(1 << int(self.rng.integers(0, 8)))
            data = bad.tobytes()
            if data.find(SYNC, 1) == -1:
                return data
        raise RuntimeError("soak: no corruption without an inner sync found")  # pragma: no cover

    def _garbage(self, m: int) -> bytes:
        """m random bytes without 0xAA (no false sync)."""
        b = self.rng.integers(0, 255, m, dtype=np.int64)
        b[b >= 0xAA] += 1
        return b.astype(np.uint8).tobytes()
