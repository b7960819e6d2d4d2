"""Coverage-guided fuzzing of one target with atheris (libFuzzer), in its own process.

``python -m fuzz.atheris_target TARGET [libFuzzer options] CORPUS_DIR``. The
imudiag modules are imported under atheris' instrumentation so libFuzzer sees
their branch coverage. A :class:`fuzz.targets.FuzzFailure` or any unexpected
exception is a crash: libFuzzer writes the input to its ``-artifact_prefix``.
"""

from __future__ import annotations

import sys

import atheris

with atheris.instrument_imports(include=["imudiag"]):
    import imudiag.certificate  # noqa: F401
    import imudiag.drivers.crc  # noqa: F401
    import imudiag.drivers.wire  # noqa: F401
    import imudiag.logs  # noqa: F401
    import imudiag.samples  # noqa: F401

from fuzz.targets import TARGETS  # noqa: E402


def main() -> None:
    name = sys.argv[1]
    check = TARGETS[name][0]

    def one_input(data: bytes) -> None:
        check(data)

    atheris.Setup([sys.argv[0], *sys.argv[2:]], one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
