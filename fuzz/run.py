"""The fuzz command: property-based (hypothesis) and coverage-guided (atheris) fuzzing, bounded.

::

    .venv/bin/python -m fuzz                         # every target, 60 s each per engine
    .venv/bin/python -m fuzz --seconds 300 --target csv --engine atheris

Targets (:mod:`fuzz.targets`): ``decoder``, ``csv``, ``npz``, ``certificate``.
A failure is saved under ``fuzz/crashes/`` (the input's bytes, replayable by
``tests/test_fuzz_short.py``, and a ``.txt`` with the example and traceback);
the command exits 1 when anything was found. atheris is optional: where it is
not installed (``pip install atheris``) the command says so and runs hypothesis.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import re
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .targets import TARGETS, dump_doc, seed_certificate_doc, seed_csv, seed_npz, seed_stream

CRASH_DIR = Path(__file__).resolve().parent / "crashes"
ROOT = Path(__file__).resolve().parent.parent
BATCH = 100  #: hypothesis examples per call of the property


def save_crash(target: str, engine: str, data: bytes, text: str) -> Path:
    """Write a failing input (bytes) and its description; returns the input's path."""
    CRASH_DIR.mkdir(parents=True, exist_ok=True)
    digest = hashlib.sha1(data).hexdigest()[:12]
    path = CRASH_DIR / f"{target}-{engine}-{digest}.bin"
    path.write_bytes(data)
    path.with_suffix(".txt").write_text(text, encoding="utf-8")
    return path


def run_hypothesis(target: str, seconds: float, seed: int = 0) -> dict[str, Any]:
    """Run ``target``'s property in batches of BATCH examples until ``seconds`` pass."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import seed as hseed

    from .strategies import PROPERTIES

    strategy, prop, to_bytes = PROPERTIES[target]
    calls = [0]
    failing: dict[str, Any] = {}

    def wrapped(x: Any) -> None:
        calls[0] += 1
        try:
            prop(x)
        except Exception:
            failing["x"] = x
            raise

    start = time.monotonic()
    batch = 0
    crash = None
    while time.monotonic() - start < seconds:
        test = hseed(seed * 1_000_003 + batch)(
            settings(
                max_examples=BATCH,
                deadline=None,
                database=None,
                derandomize=False,
                suppress_health_check=list(HealthCheck),
                print_blob=False,
            )(given(strategy)(wrapped))
        )
        batch += 1
        try:
            test()
        except Exception as exc:  # hypothesis re-raises the shrunk example's error
            x = failing.get("x")
            text = f"target {target}, hypothesis\nexample: {x!r}\n\n" + "".join(
                traceback.format_exception(exc)
            )
            crash = str(
                save_crash(target, "hypothesis", to_bytes(x) if x is not None else b"", text)
            )
            break
    return {
        "engine": "hypothesis",
        "target": target,
        "seconds": time.monotonic() - start,
        "calls": calls[0],
        "crash": crash,
    }


def write_corpus(target: str, directory: Path) -> None:
    """Valid seed inputs for the coverage-guided fuzzer."""
    rng = np.random.default_rng(0)
    for i in range(4):
        if target == "decoder":
            data = seed_stream(rng, 10 + 10 * i)
        elif target == "csv":
            data = seed_csv(rng, 2 + 3 * i).encode("utf-8")
        elif target == "npz":
            data = seed_npz(rng, 2 + 3 * i, compressed=bool(i % 2))
        else:
            data = dump_doc(seed_certificate_doc()).encode("utf-8")
        (directory / f"seed{i}").write_bytes(data)


def replay(target: str, data: bytes) -> str:
    """The traceback of ``target`` on ``data`` in this process (or that it passes now)."""
    try:
        TARGETS[target][0](data)
    except Exception as exc:
        return "".join(traceback.format_exception(exc))
    return "passes when replayed in-process"


def atheris_available() -> bool:
    """True when atheris can be imported in this environment."""
    return importlib.util.find_spec("atheris") is not None


def run_atheris(target: str, seconds: float, seed: int = 0) -> dict[str, Any]:
    """libFuzzer through atheris on ``target`` for ``seconds``, in a subprocess."""
    with tempfile.TemporaryDirectory() as tmp:
        corpus = Path(tmp) / "corpus"
        corpus.mkdir()
        write_corpus(target, corpus)
        artifacts = Path(tmp) / "artifacts"
        artifacts.mkdir()
        cmd = [
            sys.executable,
            "-m",
            "fuzz.atheris_target",
            target,
            f"-max_total_time={max(1, int(seconds))}",
            f"-seed={seed + 1}",
            f"-artifact_prefix={artifacts}/",
            "-timeout=20",
            "-rss_limit_mb=4096",
            "-print_final_stats=1",
            "-max_len=8192",
            str(corpus),
        ]
        t0 = time.monotonic()
        proc = subprocess.run(
            cmd, capture_output=True, text=True, cwd=ROOT, timeout=seconds + 120, check=False
        )
        wall = time.monotonic() - t0
        log = proc.stderr
        execs = re.findall(r"stat::number_of_executed_units:\s*(\d+)", log)
        cov = re.findall(r"cov: (\d+)", log)
        crash = None
        found = sorted(artifacts.iterdir())
        if found:
            data = found[0].read_bytes()
            crash = str(
                save_crash(
                    target,
                    "atheris",
                    data,
                    f"target {target}, atheris\n\n{replay(target, data)}\n"
                    f"libFuzzer log (end):\n{log[-1500:]}",
                )
            )
        elif proc.returncode != 0:
            crash = f"atheris exited {proc.returncode}: {log[-1500:]}"
    return {
        "engine": "atheris",
        "target": target,
        "seconds": wall,
        "calls": int(execs[-1]) if execs else None,
        "coverage": int(cov[-1]) if cov else None,
        "crash": crash,
    }


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m fuzz", description=__doc__.splitlines()[0])
    p.add_argument(
        "--seconds", type=float, default=60.0, help="seconds per target and engine (default 60)"
    )
    p.add_argument(
        "--target",
        action="append",
        choices=sorted(TARGETS),
        help="fuzz only this target (repeatable; default all)",
    )
    p.add_argument("--engine", choices=("hypothesis", "atheris", "both"), default="both")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    a = p.parse_args(argv)
    targets = a.target or list(TARGETS)
    engines = ["hypothesis", "atheris"] if a.engine == "both" else [a.engine]
    found = 0
    for engine in engines:
        if engine == "atheris" and not atheris_available():
            print("atheris: not installed in this environment (pip install atheris); skipped")
            continue
        for target in targets:
            run = run_atheris if engine == "atheris" else run_hypothesis
            r = run(target, a.seconds, a.seed)
            extra = f", coverage {r['coverage']}" if r.get("coverage") is not None else ""
            status = f"CRASH -> {r['crash']}" if r["crash"] else "clean"
            print(
                f"{engine:10s} {target:11s} {r['seconds']:6.1f} s  "
                f"{r['calls'] if r['calls'] is not None else '?':>9} inputs{extra}  {status}",
                flush=True,
            )
            found += bool(r["crash"])
    return 1 if found else 0
