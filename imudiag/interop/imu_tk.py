"""imu_tk (github.com/Kyle-ak/imu_tk) ``.calib`` files: one per triad.

``CalibratedTriad::save`` writes three Eigen blocks separated by blank lines: the 3x3
misalignment matrix T, the 3x3 scale matrix K (diagonal) and the 3x1 bias vector B, with
the model ``X' = T K (X - B)`` (raw X -> calibrated X'). imu_tk calibrates the
accelerometers to its gravity magnitude (m/s^2 when set in m/s^2, as its test program
does) and the gyros in rad/s, so the calibrated side is SI. The certificate's forward
matrix is the inverse: ``M = (T K)^-1``, ``U = B + M x``. The two files are named
``PREFIX_acc.calib`` and ``PREFIX_gyro.calib`` (imu_tk's test program's names).
"""

from __future__ import annotations

import numpy as np

from ..atomic import write_text_atomic
from ..errors import BadInput
from .model import Interchange, TriadCal, invertible

#: File name endings of the two files, as imu_tk's test program writes them.
SUFFIX = {"accel": "_acc.calib", "gyro": "_gyro.calib"}
BLOCKS = (("T", (3, 3)), ("K", (3, 3)), ("B", (3, 1)))


def paths(prefix: str) -> dict[str, str]:
    """The two file paths of a prefix: ``{"accel": PREFIX_acc.calib, "gyro": ...}``; a
    prefix that is already one of the two files names the pair."""
    for suffix in SUFFIX.values():
        if prefix.endswith(suffix):
            prefix = prefix[: -len(suffix)]
    return {name: prefix + suffix for name, suffix in SUFFIX.items()}


def _blocks(path: str) -> dict[str, np.ndarray]:
    try:
        with open(path, encoding="utf-8") as fh:
            lines = fh.read().splitlines()
    except OSError as exc:
        raise BadInput(f"{path}: cannot read: {exc.strerror or exc}") from None
    groups: list[list[tuple[int, list[str]]]] = [[]]
    for number, line in enumerate(lines, start=1):
        if line.strip():
            groups[-1].append((number, line.split()))
        elif groups[-1]:
            groups.append([])
    groups = [g for g in groups if g]
    if len(groups) < len(BLOCKS):
        missing = BLOCKS[len(groups)][0]
        raise BadInput(f"{path}: {missing}: missing (expected T, K and B blocks)")
    if len(groups) > len(BLOCKS):
        raise BadInput(f"{path}: line {groups[3][0][0]}: unexpected text after the B block")
    out = {}
    for (key, shape), group in zip(BLOCKS, groups, strict=True):
        rows, cols = len(group), {len(tokens) for _, tokens in group}
        if rows != shape[0] or cols != {shape[1]}:
            got = f"{rows} rows of {'/'.join(str(c) for c in sorted(cols))} numbers"
            raise BadInput(
                f"{path}: line {group[0][0]}: {key}: expected a {shape[0]}x{shape[1]} "
                f"matrix, got {got}"
            )
        values = []
        for number, tokens in group:
            try:
                values.append([float(v) for v in tokens])
            except ValueError:
                raise BadInput(f"{path}: line {number}: {key}: not a number in {tokens}") from None
        arr = np.array(values)
        if not np.all(np.isfinite(arr)):
            raise BadInput(f"{path}: line {group[0][0]}: {key}: not all finite numbers")
        out[key] = arr
    return out


def read_triad(path: str) -> TriadCal:
    """One ``.calib`` file as a triad: forward matrix per SI unit, bias in raw units."""
    b = _blocks(path)
    invertible(b["T"], path, "T")
    k = b["K"]
    if np.any(k - np.diag(np.diag(k))):
        raise BadInput(f"{path}: K: the scale matrix must be diagonal")
    invertible(k, path, "K")
    return TriadCal(matrix=np.linalg.inv(b["T"] @ k), bias=b["B"][:, 0])


def read(accel: str, gyro: str) -> Interchange:
    """The two files of an imu_tk calibration."""
    ic = Interchange(accel=read_triad(accel), gyro=read_triad(gyro))
    ic.notes.append(
        "imu_tk: calibrated units taken as m/s^2 and rad/s (imu_tk's gravity magnitude in m/s^2)"
    )
    return ic


def _eigen_text(m: np.ndarray) -> str:
    """A matrix as Eigen's ``operator<<`` lays it out (right-aligned columns), full precision."""
    cells = [[repr(float(v)) for v in row] for row in m]
    width = max(len(c) for row in cells for c in row)
    return "\n".join(" ".join(c.rjust(width) for c in row) for row in cells)


def triad_text(tri: TriadCal, name: str) -> str:
    """The ``.calib`` text of a triad: T, K, B as imu_tk's ``save`` writes them."""
    if tri.matrix is None or tri.bias is None:
        raise BadInput(f"{name}: the certificate has no matrix or bias to export")
    a = np.linalg.inv(tri.matrix)  # T K, raw -> SI
    if np.any(np.diag(a) == 0):
        raise BadInput(f"{name}: T K has a zero diagonal entry: no unit-diagonal T exists")
    k = np.diag(np.diag(a))
    t = a / np.diag(a)[None, :]
    blocks = [_eigen_text(t), _eigen_text(k), _eigen_text(np.asarray(tri.bias).reshape(3, 1))]
    return "\n\n".join(blocks) + "\n\n"


def write(ic: Interchange, prefix: str) -> list[str]:
    """Write ``PREFIX_acc.calib`` and ``PREFIX_gyro.calib``; returns the paths written."""
    texts = {name: triad_text(ic.triad(name), name) for name in SUFFIX}
    out = paths(prefix)
    for name, text in texts.items():
        write_text_atomic(out[name], text)
    if ic.gyro.g_sensitivity is not None and np.any(ic.gyro.g_sensitivity):
        ic.notes.append("imu_tk: no g-sensitivity in its model: gyro.g_sensitivity not exported")
    ic.notes.append("imu_tk: noise and sample rate are not part of its files: not exported")
    return [out["accel"], out["gyro"]]


__all__ = ["SUFFIX", "paths", "read", "read_triad", "triad_text", "write"]
