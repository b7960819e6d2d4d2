"""The still detector's window statistics over a stream: the means, variances and rates
of each trailing window, from prefix sums of the outputs carried across blocks (one
subtraction per window whatever its length). The part of the detector that does not
depend on its noise figures, so two detectors of one stream can share it
(:mod:`imudiag.quasistatic.pool`)."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from ..certificate import Certificate
from ..kernels import kernel
from ..samples import (
    FLAG_ACCEL_SATURATED,
    FLAG_ADC_ERROR,
    FLAG_GYRO_SATURATED,
    FLAG_SELF_TEST,
    SampleBlock,
)
from ..trailing import PrefixSums

#: Flag bits that make a sample unusable for the static check (and so for F0 and the
#: diagnosis intervals): saturation, ADC errors, and self-test, whose outputs are
#: deflected on purpose.
BAD_FLAGS = FLAG_GYRO_SATURATED | FLAG_ACCEL_SATURATED | FLAG_ADC_ERROR | FLAG_SELF_TEST


class WindowStats:
    """What a block's trailing windows hold, whatever the noise figures: the part of the
    still detector two detectors of one stream with different noise share (:mod:`.pool`).

    Rows are the block's samples from ``skip`` on (the first ``W - 1`` of a stream have no
    whole window), stream rows from ``first``; prefix-sum differences and back values
    (M, 13): outputs centred on the stream's first sample ``ref`` (0-5), their squares
    (6-11), bad flags (12).
    """

    __slots__ = ("skip", "idx", "first", "sums", "long_sums", "back_w", "back_2w", "var",
                 "mean", "_stage", "_rates")  # fmt: skip

    def __init__(
        self,
        stage: WindowStage,
        n: int,
        idx: np.ndarray,
        sums: np.ndarray,
        long_sums: np.ndarray,
        back_w: np.ndarray,
        back_2w: np.ndarray,
    ) -> None:
        w = stage.window
        self.skip = max(0, w - 1 - int(idx[0]))  #: leading rows without a whole window
        if self.skip >= n:
            return
        sl = slice(self.skip, None)
        self.idx = idx[sl]  #: (M,) stream row of each window's last sample
        self.first = int(self.idx[0])
        self.sums = sums[sl]  #: (M, 13) the window's sums
        self.long_sums = long_sums[sl]  #: (M, 13) the sums over rate_window rows
        self.back_w, self.back_2w = back_w[sl], back_2w[sl]  #: P one and two windows back
        assert stage.ref is not None
        compiled = kernel("window_moments")  # the same element-wise operations, compiled
        if compiled is not None:
            self.var, self.mean = compiled(self.sums, int(w), np.asarray(stage.ref, dtype=float))
        else:
            s1 = self.sums[:, :6]
            mean_c = s1 / w
            #: (M, 6) window variances, output units^2
            self.var = np.maximum((self.sums[:, 6:12] - s1 * mean_c) / (w - 1), 0.0)
            self.mean = mean_c + stage.ref  #: (M, 6) window means, output units
        self._stage = stage
        self._rates: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def rates(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The gyro rate about the vertical (the certificate-corrected accelerometer window
        mean) of the window means and of the longer means over ``rate_window`` rows, and
        the window means' rate magnitude (M,) each, gyro input units; worked out once."""
        if self._rates is None:
            stage = self._stage
            cert, mean = stage.certificate, self.mean
            m = mean.shape[0]
            first, rate_window = self.first, stage.rate_window
            if first + 1 >= rate_window:
                count: np.ndarray | int = rate_window
            else:
                count = np.minimum(np.arange(first + 1, first + 1 + m), rate_window)[:, None]
            assert stage.ref is not None
            compiled = kernel("window_rates") if getattr(stage, "simple_inverse", False) else None
            if compiled is not None:  # the same figures compiled, equal to rounding
                g, a = cert.gyro, cert.accel
                self._rates = compiled(
                    np.ascontiguousarray(mean), np.ascontiguousarray(self.long_sums),
                    np.ascontiguousarray(np.broadcast_to(count, (m, 1))[:, 0], dtype=float),
                    stage.ref, np.ascontiguousarray(g.bias, dtype=float),
                    np.ascontiguousarray(g.scale_factor, dtype=float),
                    np.ascontiguousarray(stage.n_inv_t["gyro"]),  # (N^-1)^T: F order
                    np.ascontiguousarray(a.bias, dtype=float),
                    np.ascontiguousarray(a.scale_factor, dtype=float),
                    np.ascontiguousarray(stage.n_inv_t["accel"]),
                )  # fmt: skip
                return self._rates
            gyro_long = self.long_sums[:, 0:3] / count + stage.ref[0:3]
            # the window means and the longer means in one pass (gyro input units)
            rates = cert.gyro.inverse(
                np.concatenate([mean[:, 0:3], gyro_long]), n_inv_t=stage.n_inv_t["gyro"]
            )
            rate = rates[:m]
            down = cert.accel.inverse(mean[:, 3:6], n_inv_t=stage.n_inv_t["accel"])
            norm = np.sqrt(np.einsum("ij,ij->i", down, down))
            norm = np.where(norm > 0, norm, 1.0)
            # about the vertical: the window means' rates and the longer means' (2, M)
            vertical, vertical_long = np.einsum("kij,ij->ki", rates.reshape(2, m, 3), down) / norm
            magnitude = np.sqrt(np.einsum("ij,ij->i", rate, rate))
            self._rates = (vertical, vertical_long, magnitude)
        return self._rates


class WindowStage:
    """The still detector's window sums over a stream: prefix sums of the outputs, their
    squares and the bad flags, carried across blocks (see
    :class:`~imudiag.quasistatic.QuasiStaticDetector`).
    ``window`` and ``rate_window`` in samples; ``cols``: the output columns (gyro 0-2,
    accel 3-5) whose non-finite values make a sample bad."""

    def __init__(
        self,
        certificate: Certificate,
        window: int,
        rate_window: int,
        cols: np.ndarray,
        n_inv_t: dict[str, np.ndarray],
    ) -> None:
        self.certificate = certificate
        self.window, self.rate_window = window, rate_window
        self.cols, self.n_inv_t = cols, n_inv_t
        self.col_mask = np.zeros(6, dtype=bool)  #: ``cols`` as a mask (the compiled rows)
        self.col_mask[np.asarray(cols, dtype=np.intp)] = True
        self.prefix = PrefixSums(13, max(rate_window, 2 * window))
        #: the certificate's inverse is (u - bias) / scale then N^-1 (no temperature or
        #: nonlinearity terms): the compiled rates apply (:meth:`WindowStats.rates`)
        self.simple_inverse = all(
            t.nonlinearity is None and t.temperature is None
            for t in (certificate.gyro, certificate.accel)
        )
        self.offsets = np.array([window, rate_window, 2 * window])
        self.ref: np.ndarray | None = None  #: the stream's first sample, the sums' origin

    def key(self) -> tuple[Any, ...]:
        """What makes two stages give the same statistics on the same blocks."""
        return (id(self.certificate), self.window, self.rate_window, tuple(self.cols.tolist()))

    def copy(self) -> WindowStage:
        """An independent copy in the present state."""
        new = copy.copy(self)
        new.prefix = self.prefix.copy()
        return new

    def run(self, block: SampleBlock) -> WindowStats:
        """The window statistics of a block (N >= 1 samples), the stream's next."""
        n = len(block)
        compiled = kernel("window_rows")
        if compiled is not None:  # the same rows compiled (the same operations: exact)
            if self.ref is None:
                x0 = np.concatenate([block.gyro[0], block.accel[0]])
                self.ref = np.where(np.isfinite(x0), x0, 0.0).astype(float)
            rows = np.empty((n, 13))
            flags = np.zeros(0, dtype=np.int64) if block.flags is None else block.flags
            compiled(
                np.asarray(block.gyro, dtype=float), np.asarray(block.accel, dtype=float),
                np.ascontiguousarray(flags, dtype=np.int64), int(BAD_FLAGS),
                self.col_mask, self.ref, rows,
            )  # fmt: skip
            return self._stats(n, rows)
        x_new = np.concatenate([block.gyro, block.accel], axis=1)
        bad_new = None
        if block.flags is not None:
            bad_new = (np.asarray(block.flags).astype(np.int64) & BAD_FLAGS) != 0
        finite = np.isfinite(x_new)
        if not finite.all():
            unusable = ~np.all(finite[:, self.cols], axis=1)
            bad_new = unusable if bad_new is None else bad_new | unusable
            x_new = np.where(finite, x_new, 0.0)
        # running sums of the window: prefix sums of the outputs (centred on the stream's
        # first sample, so squares of ADC counts stay small), their squares and the bad
        # flags; each window's sums are two rows of them, whatever the window's length
        if self.ref is None:
            self.ref = np.array(x_new[0], dtype=float)
        rows = np.empty((n, 13))
        xc = np.subtract(x_new, self.ref, out=rows[:, :6])
        np.multiply(xc, xc, out=rows[:, 6:12])
        rows[:, 12] = 0.0 if bad_new is None else bad_new
        return self._stats(n, rows)

    def _stats(self, n: int, rows: np.ndarray) -> WindowStats:
        """The window statistics of a block's ``rows`` (N, 13) (:meth:`run`)."""
        # P at each row and one window, rate_window rows and two windows back: the sums of
        # the window (``sums``) and of the rate_window rows (``long_sums``: the gyro means)
        if self.prefix.whole(n):  # diagnose-sized: slices of one array, no gathers
            now, (back_w, back_long, back_2w), idx = self.prefix.update_views(rows, self.offsets)
            sums, long_sums = now - back_w, now - back_long
        else:
            now, back, idx = self.prefix.update(rows, self.offsets)
            both = now[:, None, :] - back[:, :2, :]
            sums, long_sums = both[:, 0], both[:, 1]
            back_w, back_2w = back[:, 0], back[:, 2]
        return WindowStats(self, n, idx, sums, long_sums, back_w, back_2w)
