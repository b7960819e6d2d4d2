"""Trailing-window sums over a stream of rows, carried across blocks (running sums), and
where a window's median is certainly above or below a threshold (counts, no sorting; the
counts compiled where the kernels are on, :mod:`imudiag.kernels`: the same integers)."""

from __future__ import annotations

import copy

import numpy as np

from .kernels import kernel

#: rows between exact re-summations of the window (bounds the running sum's rounding drift)
_RESUM_ROWS = 1 << 16


class TrailingSum:
    """Sum of the last ``window`` rows ending at each new row, for a stream fed in blocks.

    Rows are (N, k) arrays (or (N,) vectors). The first ``window - 1`` rows of
    the stream have shorter windows; :meth:`update` returns the row count of
    each window alongside the sums so callers can require full windows.

    The work per block is proportional to the block, not to the window: a
    running sum of the window is kept with the window's rows in a circular
    buffer, and each new row adds itself and takes off the row that leaves
    (one cumulative sum of the differences per block). The sum is recomputed
    exactly every ``2**16`` rows so rounding cannot drift. A non-finite value
    makes the sums of the windows that hold it NaN (per column), and only those.
    """

    def __init__(self, window: int, width: int | None = None) -> None:
        if window < 1:
            raise ValueError(f"trailing window must be >= 1 row, got {window}")
        self.window = int(window)
        self._shape: tuple[int, ...] = () if width is None else (int(width),)
        self._hist = np.zeros((self.window,) + self._shape)  # circular; zeros before the start
        self._head = 0  # index of the oldest row (the next one written)
        self._rows = 0  # rows seen
        self._sum = np.zeros(self._shape)  # sum of the finite rows in the window
        self._bad_until = np.full(self._shape, -1, dtype=np.int64)  # last window with a NaN
        self._next_resum = _RESUM_ROWS

    def update(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(sums, counts) for each row of ``rows``: sums has the rows' shape, counts (N,)."""
        rows = np.asarray(rows, dtype=float)
        n = rows.shape[0]
        w = self.window
        first = self._rows
        idx = np.arange(first, first + n)
        counts = np.minimum(idx + 1, w)
        finite = np.isfinite(rows)
        if not finite.all():
            bad = np.where(finite, -1, idx.reshape((n,) + (1,) * len(self._shape)))
            self._bad_until = np.maximum(self._bad_until, bad.max(axis=0) + w - 1)
            rows = np.where(finite, rows, 0.0)
        if n >= w:
            seq = np.concatenate([self._ordered(), rows])
            c = np.cumsum(seq, axis=0)
            sums = c[w:] - c[:-w]
            self._hist = seq[-w:].copy()
            self._head = 0
            self._sum = self._hist.sum(axis=0)
        else:
            h = self._head
            end = h + n
            if end <= w:
                drop = self._hist[h:end]
                sums = self._sum + np.cumsum(rows - drop, axis=0)
                self._hist[h:end] = rows
            else:
                drop = np.concatenate([self._hist[h:], self._hist[: end - w]])
                sums = self._sum + np.cumsum(rows - drop, axis=0)
                self._hist[h:] = rows[: w - h]
                self._hist[: end - w] = rows[w - h :]
            self._head = end % w
            self._sum = sums[-1].copy()
        self._rows += n
        if self._rows >= self._next_resum:
            self._sum = self._hist.sum(axis=0)
            self._next_resum = self._rows + _RESUM_ROWS
        if np.any(self._bad_until >= first):
            sums = np.where(idx.reshape((n,) + (1,) * len(self._shape)) <= self._bad_until,
                            np.nan, sums)  # fmt: skip
        return sums, counts

    def _ordered(self) -> np.ndarray:
        """The window's rows, oldest first (zeros before the stream's start)."""
        h = self._head
        return np.concatenate([self._hist[h:], self._hist[:h]]) if h else self._hist


class PrefixSums:
    """Prefix sums of a stream of rows, the last ones kept in a circular buffer.

    The sum of the ``w`` rows ending at stream row ``s`` is ``P[s] - P[s - w]``
    (``P[j] = 0`` before the stream's start), so any number of trailing windows
    up to ``reach`` rows long come from one cumulative sum of each new block and
    one gather: the work per block is proportional to the block, whatever the
    windows. All stored sums are shifted back to zero every ``2**20`` rows so
    they never grow large enough to lose precision; differences are unchanged.
    Rows must be finite (callers zero non-finite values and count them in a
    column of their own).
    """

    def __init__(self, width: int, reach: int) -> None:
        if reach < 1:
            raise ValueError(f"prefix-sum reach must be >= 1 row, got {reach}")
        self.width = int(width)
        self.reach = int(reach)
        self.depth = 1 << int(reach + 1024).bit_length()  # power of two > reach + 1024
        self._p = np.zeros((self.depth, self.width))  # slot s % depth holds P[s]
        self._last = np.zeros(self.width)  # P of the last row
        self._rows = 0  #: rows seen
        self._next_rebase = 1 << 20

    def copy(self) -> PrefixSums:
        """An independent copy in the present state."""
        new = copy.copy(self)
        new._p = self._p.copy()
        new._last = self._last.copy()
        return new

    def update_views(
        self, rows: np.ndarray, offsets: np.ndarray
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...], np.ndarray]:
        """As :meth:`update`, with P ``offsets[j]`` rows back as the j-th of a tuple of
        (N, k) arrays: on a block longer than the buffer's free span these are views of one
        array of the block's prefix sums (no gathers, no copies), with the values
        :meth:`update` gives bit for bit."""
        n = rows.shape[0]
        if not self.whole(n):
            now, back, idx = self.update(rows, offsets)
            return now, tuple(back[:, j] for j in range(back.shape[1])), idx
        ext, idx = self._whole(rows)
        reach = self.reach
        backs = tuple(ext[reach - off : reach - off + n] for off in offsets.tolist())
        return ext[reach:], backs, idx

    def _whole(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The one pass of :meth:`update_views` over a block (``whole``): ``ext`` (reach + N,
        k), the ``reach`` prefix sums before the block then the block's, and the stream index
        of each new row (N,)."""
        n = rows.shape[0]
        first = self._rows
        reach, depth, mask = self.reach, self.depth, self.depth - 1
        # ext[reach + i]: P at new row i; ext[reach - off + i]: P ``off`` rows before it
        ext = np.empty((reach + n, self.width))
        h0 = first - reach  # stream row of ext[0]
        z = min(reach, max(0, -h0))  # rows before the stream's start: P = 0
        ext[:z] = 0.0
        s = (h0 + z) & mask
        e = min(depth, s + reach - z)
        ext[z : z + e - s] = self._p[s:e]
        ext[z + e - s : reach] = self._p[: reach - z - (e - s)]
        # the cumulative sums in the chunks the buffer allows, so every value is rounded as
        # the chunked update rounds it (the sum of a chunk, then the last P added)
        chunk = depth - reach - 1
        compiled = kernel("chunked_cumsum")  # the same additions in one pass: bit for bit
        if compiled is not None:
            compiled(np.ascontiguousarray(rows, dtype=float), self._last, chunk, ext[reach:])
        else:
            last = self._last
            for a in range(0, n, chunk):
                seg = ext[reach + a : reach + min(n, a + chunk)]
                np.cumsum(rows[a : a + chunk], axis=0, out=seg)
                seg += last
                last = seg[-1]
        # the buffer keeps the last ``depth`` rows' P in their slots
        keep = min(n, depth)
        s = (first + n - keep) & mask
        e = min(depth, s + keep)
        self._p[s:e] = ext[reach + n - keep : reach + n - keep + e - s]
        self._p[: keep - (e - s)] = ext[reach + n - keep + e - s :]
        self._last = ext[-1].copy()
        self._rows = first + n
        return ext, np.arange(first, first + n)

    def whole(self, n: int) -> bool:
        """Whether a block of ``n`` rows goes through :meth:`update_views`' one pass: longer
        than the buffer's free span (shorter ones are one chunk already) and not reaching
        the next shift back to zero (whose chunk-by-chunk roundings only the chunked
        update repeats)."""
        return n > self.depth - self.reach - 1 and self._rows + n < self._next_rebase

    def update(
        self, rows: np.ndarray, offsets: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(P at the new rows (N, k), P ``offsets`` rows back (N, len(offsets), k), stream
        index of each new row (N,)); ``rows`` (N, k), each offset in 1..reach."""
        n = rows.shape[0]
        chunk = self.depth - self.reach - 1
        if n > chunk:  # keep every slot a window reaches unwritten until it is read
            if self.whole(n):
                stack = kernel("stack_backs")  # the same copies compiled
                if stack is None:
                    now, backs, idx = self.update_views(rows, offsets)
                    return now, np.stack(backs, axis=1), idx
                ext, idx = self._whole(rows)
                back = np.empty((n, len(offsets), self.width))
                stack(ext, self.reach, np.asarray(offsets, dtype=np.int64), back)
                return ext[self.reach :], back, idx
            parts = [self.update(rows[i : i + chunk], offsets) for i in range(0, n, chunk)]
            return (
                np.concatenate([p[0] for p in parts]),
                np.concatenate([p[1] for p in parts]),
                np.concatenate([p[2] for p in parts]),
            )
        first = self._rows
        now = np.cumsum(rows, axis=0)
        now += self._last
        idx = np.arange(first, first + n)
        depth, mask = self.depth, self.depth - 1
        s0 = first & mask
        if s0 + n <= depth:  # contiguous slots: slices, not gathers
            self._p[s0 : s0 + n] = now
        else:
            self._p[idx & mask] = now
        back = np.empty((n, len(offsets), self.width))
        for j, off in enumerate(offsets.tolist()):
            b0 = (first - off) & mask
            if b0 + n <= depth:
                back[:, j] = self._p[b0 : b0 + n]
            else:
                back[:, j] = self._p[(idx - off) & mask]
            if first < off:  # P before the stream's start is 0
                back[: off - first, j] = 0.0
        self._last = now[-1].copy()
        self._rows = first + n
        if self._rows >= self._next_rebase:
            shift = self._last.copy()
            self._p -= shift
            self._last -= shift
            now = now - shift
            back = back - shift
            self._next_rebase = self._rows + (1 << 20)
        return now, back, idx


#: relative margin of :func:`median_side` around each threshold: a median this far beyond it
#: stays beyond it through the roundings of the caller's own comparison
MEDIAN_SIDE_MARGIN = 1e-9


def median_side(
    x: np.ndarray, ends: np.ndarray, w: int, thresholds: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Where the median of a window of ``x`` is certainly above, or certainly not above, a
    threshold, from counts of the values beyond it (no median computed).

    ``x`` (R, C) values; the windows are ``x[e - w : e]`` for ``e`` in ``ends`` (P,);
    ``thresholds`` (k, C), in the units of x. Returns ``above`` and ``below`` (P, k, C):
    ``above`` when at least ``w // 2 + 1`` of the window's values exceed the threshold
    raised by :data:`MEDIAN_SIDE_MARGIN` (then both middle values, and so ``np.median``,
    are above it); ``below`` when at most ``(w - 1) // 2`` exceed the threshold lowered by
    the margin (the median is at most that). Neither: the median is within the margin or
    the window holds a NaN; only there does a caller need the median itself.
    """
    x = np.asarray(x, dtype=float)
    thr = np.asarray(thresholds, dtype=float)
    k = thr.shape[0]
    bounds = np.concatenate([thr * (1.0 + MEDIAN_SIDE_MARGIN), thr * (1.0 - MEDIAN_SIDE_MARGIN)])
    ends = np.asarray(ends)
    compiled = kernel("beyond_counts")  # the same counts in one compiled pass (exact)
    if compiled is not None and (
        ends.size == 0 or (ends[0] >= w and bool(np.all(np.diff(ends) >= 0)))
    ):
        counts = compiled(x, bounds, ends.astype(np.int64), int(w))
    else:
        beyond = np.empty((x.shape[0] + 1, 2 * k + 1, x.shape[1]), dtype=np.int32)
        beyond[0] = 0
        np.cumsum(x[:, None, :] > bounds[None], axis=0, out=beyond[1:, : 2 * k])
        np.cumsum(np.isnan(x), axis=0, out=beyond[1:, 2 * k])
        counts = beyond[ends] - beyond[ends - w]  # (P, 2 k + 1, C)
    clean = (counts[:, 2 * k] == 0)[:, None, :]
    above = (counts[:, :k] >= w // 2 + 1) & clean
    below = (counts[:, k : 2 * k] <= (w - 1) // 2) & clean
    return above, below
