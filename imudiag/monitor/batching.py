"""The monitor's F0 screen (issue 14): reads are gathered and checked once per batch,
unless they could change an F0 verdict. :class:`F0Screen` counts the samples of the reads
gathered that are beyond their F0 limit, whether or not the unit was still: a bound on
the failures those reads can add."""

from __future__ import annotations

import numpy as np

from ..certificate import Certificate
from ..samples import SampleBlock


def count_beyond(x: np.ndarray, scale: float, limit: float) -> int:
    """How many rows of ``x`` (N, 3) times ``scale`` have |F0| = |(|row|^2 - 1) / 2| beyond
    ``limit`` (NaN rows never do, as in the F0 check)."""
    q = np.einsum("ij,ij->i", x, x)
    q *= 0.5 * scale * scale
    q -= 0.5
    # a hair inside the limit: rounding here (not the F0 check's order of operations) must
    # never let a sample the check fails pass as harmless
    return int(np.count_nonzero(np.abs(q) > limit * (1.0 - 1e-9)))


class F0Screen:
    """Samples beyond the F0 limit among gathered reads, per triad. ``n_inv_t``: the
    certificate's inverse matrices per triad; ``limit``: each triad's F0 limit."""

    def __init__(
        self, certificate: Certificate, n_inv_t: dict[str, np.ndarray], limit: dict[str, float]
    ) -> None:
        self.certificate = certificate
        self.n_inv_t = n_inv_t
        self.limit = limit
        #: accelerometer input units -> fractions of gravity
        self.accel_scale = certificate.accel.unit_to_si / certificate.gravity
        # a linear accelerometer model (no temperature or nonlinearity block): the F0
        # screen of every read as the bias and one matrix to fractions of g
        acc = certificate.accel
        self.accel_linear: tuple[np.ndarray, np.ndarray] | None = None
        if acc.temperature is None and acc.nonlinearity is None:
            to_g = n_inv_t["accel"] / np.asarray(acc.scale_factor, float)[:, None]
            self.accel_linear = (np.asarray(acc.bias, float), to_g * self.accel_scale)

    def count(self, parts: list[SampleBlock], gyro_f0: bool) -> dict[str, int]:
        """Samples of the reads ``parts`` beyond the accelerometer's F0 limit, and the
        gyro's where ``gyro_f0`` (its F0 on Earth rate is checked)."""
        cert = self.certificate
        beyond = {"accel": 0, "gyro": 0}
        if self.accel_linear is not None and not gyro_f0:
            # bias and (scale factor, N^-1, units, gravity) folded into one matrix
            bias, to_g = self.accel_linear
            accel = parts[0].accel if len(parts) == 1 else np.concatenate([b.accel for b in parts])
            beyond["accel"] = count_beyond((accel - bias) @ to_g, 1.0, self.limit["accel"])
            return beyond
        block = parts[0] if len(parts) == 1 else SampleBlock.concat(parts)
        accel_in = cert.accel.inverse(block.accel, temp_c=block.temp,
                                      n_inv_t=self.n_inv_t["accel"])  # fmt: skip
        beyond["accel"] = count_beyond(accel_in, self.accel_scale, self.limit["accel"])
        if gyro_f0:
            gyro_si = cert.gyro.inverse_si(
                block.gyro, temp_c=block.temp, n_inv_t=self.n_inv_t["gyro"],
                accel_input=accel_in if cert.gyro.g_sensitivity is not None else None,
            )  # fmt: skip
            beyond["gyro"] = count_beyond(gyro_si, 1.0 / cert.earth_rate, self.limit["gyro"])
        return beyond
