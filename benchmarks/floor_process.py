"""The whole-process floor ``imudiag diagnose`` on a raw capture is judged against (issue 14).

A process that does the least a diagnosis of a raw capture must: start Python, import
numpy and the wire format's table CRC, read the capture in chunks of 16384 frames, and
per chunk ``frombuffer`` with the frame dtype, the table CRC of every frame, and the norms
of both triads' raw outputs (:func:`benchmarks.decode_f0.floor_frames`). Timed as a
whole process by :func:`benchmarks.run.bench_diagnose`, like the command.

Run: ``python -m benchmarks.floor_process CAPTURE.bin`` (prints the good frames).
"""

from __future__ import annotations

import sys

from imudiag.drivers.wire import SAMPLE_FRAME_SIZE

from .decode_f0 import floor_frames

CHUNK_FRAMES = 16384  #: frames per read, the replay driver's block


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m benchmarks.floor_process CAPTURE.bin", file=sys.stderr)
        return 2
    good = 0
    with open(args[0], "rb") as fh:
        while chunk := fh.read(CHUNK_FRAMES * SAMPLE_FRAME_SIZE):
            good += floor_frames(chunk)
    print(good)
    return 0


if __name__ == "__main__":
    sys.exit(main())
