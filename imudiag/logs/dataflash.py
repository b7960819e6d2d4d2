"""ArduPilot DataFlash logs (``.bin`` that starts with a FMT message) through pymavlink's
DFReader (extra ``[ardupilot]``).

A ``.bin`` is a raw wire capture unless its first bytes are a DataFlash FMT
message (``A3 95 80``): the registry's magic test tells them apart. The samples
are the ``IMU`` messages of one instance: field ``I`` in current firmware, or the
message name in older logs (``IMU``, ``IMU2``, ``IMU3`` for instances 0, 1, 2).
``--instance N`` chooses; by default the lowest, and the ``source`` metadata
lists the instances there. ``GyrX..Z`` are rad/s, ``AccX..Z`` m/s^2, ``T``
degC; ``t`` is ``TimeUS`` in s since boot. The file is parsed whole (pymavlink
reads message by message in Python), then handed out in blocks.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .base import DEFAULT_BLOCK_SIZE, ColumnsReader, LogError
from .extras import require
from .options import LogOptions

#: First bytes of a DataFlash log: the message head A3 95 and the FMT message id 128.
DATAFLASH_MAGIC = b"\xa3\x95\x80"
_NAMES = {"IMU": 0, "IMU2": 1, "IMU3": 2}


def is_dataflash(head: bytes) -> bool:
    """Whether a file's first bytes are a DataFlash log's."""
    return head.startswith(DATAFLASH_MAGIC)


class DataFlashReader(ColumnsReader):
    """Reader of the IMU messages of one instance of an ArduPilot DataFlash log."""

    format = "dataflash"

    def __init__(
        self,
        path: str | Path,
        block_size: int = DEFAULT_BLOCK_SIZE,
        options: LogOptions | None = None,
    ) -> None:
        super().__init__(path, block_size)
        self.options = options or LogOptions()
        dfreader = require("pymavlink.DFReader", "ardupilot", "ArduPilot DataFlash logs")
        head = self._read_head(len(DATAFLASH_MAGIC))
        if not is_dataflash(head):
            raise LogError(self.path, "not a DataFlash log (no FMT message at the start)")
        rows: dict[int, list[tuple[float, ...]]] = {}
        try:
            log = dfreader.DFReader_binary(self.path, zero_time_base=True)
            while True:
                m = log.recv_match(type=list(_NAMES))
                if m is None:
                    break
                name = m.get_type()
                inst = int(getattr(m, "I", _NAMES[name])) if name == "IMU" else _NAMES[name]
                rows.setdefault(inst, []).append(
                    (
                        m.TimeUS * 1e-6,
                        m.GyrX,
                        m.GyrY,
                        m.GyrZ,
                        m.AccX,
                        m.AccY,
                        m.AccZ,
                        float(getattr(m, "T", np.nan)),
                    )
                )
        except Exception as exc:  # pymavlink raises plain errors on corrupt logs
            raise LogError(self.path, f"not a readable DataFlash log: {exc}") from None
        if not rows:
            raise LogError(self.path, "no IMU messages in the DataFlash log")
        have = sorted(rows)
        listed = ", ".join(map(str, have))
        wanted = self.options.instance
        if wanted is not None and wanted not in rows:
            raise LogError(
                self.path, f"--instance {wanted}: no IMU of that instance (have {listed})"
            )
        inst = have[0] if wanted is None else wanted
        m = np.asarray(rows[inst], dtype=float)
        names = ("t", "gx", "gy", "gz", "ax", "ay", "az", "temp")
        self._cols = {n: m[:, i] for i, n in enumerate(names)}
        if not np.all(np.isfinite(self._cols["temp"])):
            del self._cols["temp"]
        how = "--instance" if wanted is not None else "the lowest; --instance N for another"
        step = float(np.median(np.diff(m[:, 0]))) if m.shape[0] > 1 else 0.0
        self.meta.update(
            {
                "source": f"DataFlash IMU instance {inst} ({how}; instances in the log: {listed})",
                "units": {"gyro": "rad/s", "accel": "m/s^2"},
                "device": f"ArduPilot DataFlash {Path(self.path).name}",
            }
        )
        if step > 0:
            self.meta["sample_rate"] = round(1.0 / step, 3)

    def _where(self, index: int) -> str:
        return f"IMU message {index + 1}"


__all__ = ["DATAFLASH_MAGIC", "DataFlashReader", "is_dataflash"]
