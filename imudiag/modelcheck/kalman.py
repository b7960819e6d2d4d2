"""Generalised least squares under a random-walk bias, by Kalman innovations.

A residual series of chunk means is modelled as

    y_i = H_i b(t_i) + X_i beta + e_i,   b a random walk (K^2 per second per state),
                                          e_i white with variance R_i.

The bias state starts diffuse (it absorbs a constant offset per sensor). The
filter is linear, so running it on y and on every regressor column at once
gives innovations ``nu`` whose whitened values ``nu / sqrt(S)`` turn the
correlated problem into ordinary least squares (the GLS of the random-walk
covariance): any subset of regressors is then fitted, tested and cross-
validated from the same innovations, or from their cross products summed over
row groups (:func:`filter_products`, memory independent of the series length).
A batch of random-walk coefficients is filtered together for profile
likelihoods. The loop runs over chunks (a few per second of data), vectorised
across columns and the batch. It runs in two passes (the variance recursion does not
depend on the data, so it goes first; then the state; on Python floats for the one-state
channels), the same floating-point operations as the row-by-row loop kept beside them
as the reference (``_GENERAL_ONLY``; tests/test_modelcheck.py compares them bit for bit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: an innovation whose state variance is above this fraction of the diffuse prior is
#: "diffuse" (it only sets the initial state) and is left out of fits and likelihoods
DIFFUSE_FRACTION = 1e-4


@dataclass
class Innovations:
    """Filter output: nu (B, n, c), S (B, n), valid (B, n) bool (used and not diffuse)."""

    nu: np.ndarray
    S: np.ndarray
    valid: np.ndarray

    def whitened(self, b: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(rows, w): the valid chunk indices and ``nu / sqrt(S)`` (m, c) of batch member b."""
        rows = np.flatnonzero(self.valid[b])
        return rows, self.nu[b, rows] / np.sqrt(self.S[b, rows])[:, None]


def run_filter(
    t: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    Z: np.ndarray,
    q: np.ndarray,
    use: np.ndarray | None = None,
    p0: np.ndarray | None = None,
) -> Innovations:
    """Innovations of data columns ``Z`` (n, c) under random-walk states.

    t (n,) s; H (n, d); R (n,) white variance; q (B, d) random-walk intensities K^2
    (state units^2 / s); ``use`` (n,) chunks to assimilate (others: time update only,
    for fitting on part of the data); p0 (d,) diffuse prior variance.
    """
    n, d = H.shape
    c = Z.shape[1]
    q = np.atleast_2d(np.asarray(q, dtype=float))
    b = q.shape[0]
    if use is None:
        use = np.ones(n, dtype=bool)
    if p0 is None:
        hh = np.maximum(np.sum(H * H, axis=1), 1e-300)
        p0 = np.full(d, 1e6 * float(np.median(R / hh)))
    nu = np.zeros((b, n, c))
    S = np.full((b, n), np.inf)
    valid = np.zeros((b, n), dtype=bool)
    if d == 1 and not _GENERAL_ONLY:
        st = _new_state(p0, b, c, float(t[0]) if n else 0.0)
        rows, nu[:, use], S[:, use], hph_m = _one_state_innovations(
            np.asarray(t, dtype=float), H[:, 0], R, Z, q, use, st
        )
        hr = H[rows, 0]
        valid[:, use] = hph_m <= DIFFUSE_FRACTION * ((hr * hr) * p0[0])
        return Innovations(nu=nu, S=S, valid=valid)
    if not _GENERAL_ONLY:
        st = _new_state(p0, b, c, float(t[0]) if n else 0.0)
        rows, nu[:, use], S[:, use], hph_m = _innovations(
            np.asarray(t, dtype=float), H, R, Z, q, use, st
        )
        hr = H[rows]
        lim = np.array([float(np.dot(hi * hi, p0)) for hi in hr])
        valid[:, use] = hph_m <= DIFFUSE_FRACTION * lim
        return Innovations(nu=nu, S=S, valid=valid)
    x = np.zeros((b, d, c))
    P = np.broadcast_to(np.diag(p0), (b, d, d)).copy()
    diag = np.arange(d)
    t_prev = float(t[0]) if n else 0.0
    for i in range(n):  # one step per chunk (not per sample)
        dt = float(t[i]) - t_prev
        t_prev = float(t[i])
        if dt > 0:
            P[:, diag, diag] += q * dt
        if not use[i]:
            continue
        h = H[i]
        ph = P @ h  # (b, d)
        hph = ph @ h  # (b,)
        s = hph + R[i]
        innov = Z[i][None, :] - np.einsum("d,bdc->bc", h, x)
        gain = ph / s[:, None]
        x += gain[:, :, None] * innov[:, None, :]
        P -= gain[:, :, None] * ph[:, None, :]
        nu[:, i] = innov
        S[:, i] = s
        valid[:, i] = hph <= DIFFUSE_FRACTION * float(np.dot(h * h, p0))
    return Innovations(nu=nu, S=S, valid=valid)


# ---------------------------------------------------------------------------
# cross products: the same filter, keeping only sums over rows (memory independent of n)


@dataclass
class Products:
    """Sums over row groups of products of whitened innovations ``w = nu / sqrt(S)``.

    head (B, G, h, h): among the head columns (y and the model's regressors);
    cross (B, G, c, h): candidate columns against the head; diag (B, G, c): candidate
    squares; block (B, G, k, k): among the first k candidate columns; log_s (B, G): sum of
    log S; rows (G,): rows summed. B batch members, G row groups.
    """

    head: np.ndarray
    cross: np.ndarray
    diag: np.ndarray
    block: np.ndarray
    log_s: np.ndarray
    rows: np.ndarray


def filter_products(
    t: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    head: np.ndarray,
    q: np.ndarray,
    groups: np.ndarray,
    use: np.ndarray | None = None,
    p0: np.ndarray | None = None,
    cand: np.ndarray | None = None,
    step_axis: np.ndarray | None = None,
    step_at: np.ndarray | None = None,
    block_k: int = 0,
    buffer_rows: int = 64,
) -> Products:
    """Run the random-walk filter on the head columns and candidate columns and return the
    cross products of their whitened innovations over the row ``groups`` (G, n) bool.

    Candidate columns are ``cand`` (n, c1) followed by bias steps generated row by row
    (never stored): step m is ``H[i, step_axis[m]]`` for rows ``i >= step_at[m]``.
    The loop runs over rows (chunks); everything inside is vectorised.
    """
    n, d = H.shape
    q = np.atleast_2d(np.asarray(q, dtype=float))
    b = q.shape[0]
    if use is None:
        use = np.ones(n, dtype=bool)
    if p0 is None:
        hh = np.maximum(np.sum(H * H, axis=1), 1e-300)
        p0 = np.full(d, 1e6 * float(np.median(R / hh)))
    if not _GENERAL_ONLY:
        return _filter_products_split(
            t, H, R, head, q, groups, use, p0, cand, step_axis, step_at, block_k, buffer_rows
        )
    c1 = 0 if cand is None else cand.shape[1]
    steps = 0 if step_axis is None else step_axis.shape[0]
    cand_rows = cand if cand is not None else np.zeros((0, 0))
    step_cols = step_axis if step_axis is not None else np.zeros(0, np.int64)
    step_rows = step_at if step_at is not None else np.zeros(0, np.int64)
    hw = head.shape[1]
    cw = c1 + steps
    width = hw + cw
    g = groups.shape[0]
    out = Products(
        head=np.zeros((b, g, hw, hw)),
        cross=np.zeros((b, g, cw, hw)),
        diag=np.zeros((b, g, cw)),
        block=np.zeros((b, g, block_k, block_k)),
        log_s=np.zeros((b, g)),
        rows=groups.sum(axis=1).astype(float),
    )
    x = np.zeros((b, d, width))
    P = np.broadcast_to(np.diag(p0), (b, d, d)).copy()
    diag_idx = np.arange(d)
    buf = np.zeros((b, buffer_rows, width))
    buf_groups = np.zeros((buffer_rows, g), dtype=bool)
    filled = 0

    def flush(k: int) -> None:
        w = buf[:, :k]
        for gi in range(g):
            sel = buf_groups[:k, gi]
            if not np.any(sel):
                continue
            ws = w[:, sel]
            wh, wc = ws[:, :, :hw], ws[:, :, hw:]
            out.head[:, gi] += np.einsum("bri,brj->bij", wh, wh)
            if cw:
                out.cross[:, gi] += np.einsum("bri,brj->bij", wc, wh)
                out.diag[:, gi] += np.einsum("bri,bri->bi", wc, wc)
            if block_k:
                wk = wc[:, :, :block_k]
                out.block[:, gi] += np.einsum("bri,brj->bij", wk, wk)

    row = np.empty(width)
    t_prev = float(t[0]) if n else 0.0
    for i in range(n):  # one step per chunk (not per sample)
        dt = float(t[i]) - t_prev
        t_prev = float(t[i])
        if dt > 0:
            P[:, diag_idx, diag_idx] += q * dt
        if not use[i]:
            continue
        h = H[i]
        row[:hw] = head[i]
        if c1:
            row[hw : hw + c1] = cand_rows[i]
        if steps:
            row[hw + c1 :] = H[i, step_cols] * (i >= step_rows)
        ph = P @ h
        s = ph @ h + R[i]
        innov = row[None, :] - np.einsum("d,bdc->bc", h, x)
        gain = ph / s[:, None]
        x += gain[:, :, None] * innov[:, None, :]
        P -= gain[:, :, None] * ph[:, None, :]
        in_groups = groups[:, i]
        if np.any(in_groups):
            out.log_s[:, in_groups] += np.log(s)[:, None]
            buf[:, filled] = innov / np.sqrt(s)[:, None]
            buf_groups[filled] = in_groups
            filled += 1
            if filled == buffer_rows:
                flush(filled)
                filled = 0
    if filled:
        flush(filled)
    return out


#: tests set this to run the row-by-row loops of run_filter and filter_products only (the
#: reference), to compare the two-pass paths with them
_GENERAL_ONLY = False
#: rows (chunks) per pass of filter_products' two-pass path: its memory does not grow
#: with the series
PASS_ROWS = 2048


@dataclass
class _State:
    """The filter's state between passes: variance P (B, d, d), state x (B, d, c), the
    time of the last row (s)."""

    P: np.ndarray
    x: np.ndarray
    t_prev: float


def _new_state(p0: np.ndarray, b: int, c: int, t0: float) -> _State:
    d = p0.shape[0]
    return _State(
        P=np.broadcast_to(np.diag(p0), (b, d, d)).copy(), x=np.zeros((b, d, c)), t_prev=t0
    )


def _one_state_innovations(
    t: np.ndarray,
    h: np.ndarray,
    R: np.ndarray,
    Z: np.ndarray,
    q: np.ndarray,
    use: np.ndarray,
    st: _State,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows ``t`` of the filter of :func:`run_filter` for one random-walk state (d = 1),
    the same floating-point operations in the same order, from the state ``st`` (updated):
    the variance recursion does not depend on the data, so it runs first over (B,)
    vectors, then the state over (B, c); with one batch member and one column both run on
    Python floats. Returns (rows used (m,), innovations (B, m, c), S (B, m), h P h (B, m))."""
    n = h.shape[0]
    b = q.shape[0]
    c = Z.shape[1]
    q0 = q[:, 0]
    rows = np.flatnonzero(use)
    m = rows.shape[0]
    tl = t.tolist()
    hl = h.tolist()
    rl = R.tolist()
    used = use.tolist()
    S = np.empty((b, m))
    gain = np.empty((b, m))
    hph = np.empty((b, m))
    t_prev = st.t_prev
    if b == 1:
        pv = float(st.P[0, 0, 0])
        qv = float(q0[0])
        sl, gl, hl_ = [0.0] * m, [0.0] * m, [0.0] * m
        j = 0
        for i in range(n):
            dt = tl[i] - t_prev
            t_prev = tl[i]
            if dt > 0:
                pv += qv * dt
            if not used[i]:
                continue
            hi = hl[i]
            ph = pv * hi
            hp = ph * hi
            si = hp + rl[i]
            g = ph / si
            pv -= g * ph
            sl[j], gl[j], hl_[j] = si, g, hp
            j += 1
        S[0], gain[0], hph[0] = sl, gl, hl_
        st.P[0, 0, 0] = pv
    else:
        pa = st.P[:, 0, 0].copy()
        j = 0
        for i in range(n):
            dt = tl[i] - t_prev
            t_prev = tl[i]
            if dt > 0:
                pa += q0 * dt
            if not used[i]:
                continue
            hi = hl[i]
            ph = pa * hi
            hp = ph * hi
            si = hp + rl[i]
            g = ph / si
            pa -= g * ph
            S[:, j], gain[:, j], hph[:, j] = si, g, hp
            j += 1
        st.P[:, 0, 0] = pa
    st.t_prev = t_prev
    nu = np.empty((b, m, c))
    if b == 1 and c == 1:
        xv = float(st.x[0, 0, 0])
        zl = Z[rows, 0].tolist()
        gl = gain[0].tolist()
        nl = [0.0] * m
        for j in range(m):
            innov = zl[j] - hl[rows[j]] * xv
            xv += gl[j] * innov
            nl[j] = innov
        nu[0, :, 0] = nl
        st.x[0, 0, 0] = xv
    else:
        x = st.x[:, 0, :].copy()
        gcol = gain[:, :, None]
        for j, i in enumerate(rows.tolist()):
            innov = Z[i][None, :] - hl[i] * x
            x += gcol[:, j] * innov
            nu[:, j] = innov
        st.x[:, 0, :] = x
    return rows, nu, S, hph


def _innovations(
    t: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    Z: np.ndarray,
    q: np.ndarray,
    use: np.ndarray,
    st: _State,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows ``t`` of the filter of :func:`run_filter` for d states from the state ``st``
    (updated), the same operations as its loop: the variance recursion first (it does not
    depend on the data), then the state. Returns (rows used (m,), innovations (B, m, c),
    S (B, m), h P h (B, m))."""
    n, d = H.shape
    b = q.shape[0]
    c = Z.shape[1]
    rows = np.flatnonzero(use)
    m = rows.shape[0]
    P = st.P
    # the diagonals of P as a view where P is C-contiguous (as _new_state makes it): the
    # same additions as P[:, diag, diag] += ..., without fancy indexing every row
    diag = np.arange(d)
    p_diag = P.reshape(b, d * d)[:, :: d + 1] if P.flags.c_contiguous and P.size else None
    S = np.empty((b, m))
    hph = np.empty((b, m))
    gains = np.empty((b, m, d))
    tl = t.tolist()
    used = use.tolist()
    t_prev = st.t_prev
    j = 0
    for i in range(n):
        dt = tl[i] - t_prev
        t_prev = tl[i]
        if dt > 0:
            if p_diag is not None:
                p_diag += q * dt
            else:
                P[:, diag, diag] += q * dt
        if not used[i]:
            continue
        h = H[i]
        ph = P @ h
        hp = ph @ h
        s = hp + R[i]
        gain = ph / s[:, None]
        P -= gain[:, :, None] * ph[:, None, :]
        S[:, j], hph[:, j], gains[:, j] = s, hp, gain
        j += 1
    st.t_prev = t_prev
    nu = np.empty((b, m, c))
    x = st.x
    for j, i in enumerate(rows.tolist()):
        innov = Z[i][None, :] - np.einsum("d,bdc->bc", H[i], x)
        x += gains[:, j, :, None] * innov[:, None, :]
        nu[:, j] = innov
    return rows, nu, S, hph


def _pass(
    t: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    Z: np.ndarray,
    q: np.ndarray,
    use: np.ndarray,
    st: _State,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One pass over rows: the one-state path or the d-state path."""
    if H.shape[1] == 1:
        return _one_state_innovations(t, H[:, 0], R, Z, q, use, st)
    return _innovations(t, H, R, Z, q, use, st)


def _filter_products_split(
    t: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    head: np.ndarray,
    q: np.ndarray,
    groups: np.ndarray,
    use: np.ndarray,
    p0: np.ndarray,
    cand: np.ndarray | None,
    step_axis: np.ndarray | None,
    step_at: np.ndarray | None,
    block_k: int,
    buffer_rows: int,
) -> Products:
    """:func:`filter_products` in passes of :data:`PASS_ROWS` rows, each in two steps: the
    innovations of its rows (:func:`_pass`), then the whitened rows summed in the same
    buffers of ``buffer_rows`` rows in the same order as the row-by-row loop
    (bit-identical results, tests/test_modelcheck.py compares the two); memory does not
    grow with the series."""
    t = np.asarray(t, dtype=float)
    n = H.shape[0]
    b = q.shape[0]
    hw = head.shape[1]
    c1 = 0 if cand is None else cand.shape[1]
    steps = 0 if step_axis is None or step_at is None else step_axis.shape[0]
    width = hw + c1 + steps
    cw = width - hw
    g = groups.shape[0]
    out = Products(
        head=np.zeros((b, g, hw, hw)),
        cross=np.zeros((b, g, cw, hw)),
        diag=np.zeros((b, g, cw)),
        block=np.zeros((b, g, block_k, block_k)),
        log_s=np.zeros((b, g)),
        rows=groups.sum(axis=1).astype(float),
    )
    st = _new_state(p0, b, width, float(t[0]) if n else 0.0)
    pending_w = np.zeros((b, 0, width))  # whitened rows not yet summed (< buffer_rows)
    pending_g = np.zeros((g, 0), dtype=bool)

    def flush(w: np.ndarray, in_g: np.ndarray) -> None:
        for gi in range(g):
            sel = in_g[gi]
            if not np.any(sel):
                continue
            ws = w[:, sel]
            wh, wc = ws[:, :, :hw], ws[:, :, hw:]
            out.head[:, gi] += np.einsum("bri,brj->bij", wh, wh)
            if cw:
                out.cross[:, gi] += np.einsum("bri,brj->bij", wc, wh)
                out.diag[:, gi] += np.einsum("bri,bri->bi", wc, wc)
            if block_k:
                wk = wc[:, :, :block_k]
                out.block[:, gi] += np.einsum("bri,brj->bij", wk, wk)

    for a in range(0, n, PASS_ROWS):
        e = min(a + PASS_ROWS, n)
        cols = [head[a:e]]
        if cand is not None:
            cols.append(cand[a:e])
        if steps:
            assert step_axis is not None and step_at is not None
            idx = np.arange(a, e)[:, None]
            cols.append(H[a:e, step_axis] * (idx >= step_at[None, :]))
        Z = np.concatenate(cols, axis=1) if len(cols) > 1 else cols[0]
        rows, nu, S, _ = _pass(t[a:e], H[a:e], R[a:e], Z, q, use[a:e], st)
        in_groups = groups[:, a:e][:, rows]  # (G, m)
        keep = np.any(in_groups, axis=0)
        if not np.any(keep):
            continue
        S = S[:, keep]
        in_groups = in_groups[:, keep]
        # the log S sums row by row, in row order (cumsum adds sequentially, as the loop
        # did, from the sum so far)
        log_s = np.log(S)
        for gi in range(g):
            sel = in_groups[gi]
            if np.any(sel):
                seq = np.concatenate([out.log_s[:, gi : gi + 1], log_s[:, sel]], axis=1)
                out.log_s[:, gi] = np.cumsum(seq, axis=1)[:, -1]
        w_all = np.concatenate([pending_w, nu[:, keep] / np.sqrt(S)[:, :, None]], axis=1)
        g_all = np.concatenate([pending_g, in_groups], axis=1)
        m = w_all.shape[1]
        full = m - m % buffer_rows
        for start in range(0, full, buffer_rows):
            stop = start + buffer_rows
            flush(w_all[:, start:stop], g_all[:, start:stop])
        pending_w, pending_g = w_all[:, full:].copy(), g_all[:, full:].copy()
    if pending_w.shape[1]:
        flush(pending_w, pending_g)
    return out


def pinv_sym(a: np.ndarray, rtol: float = 1e-10) -> tuple[np.ndarray, int]:
    """Pseudo-inverse of a symmetric positive semi-definite matrix and its numerical rank."""
    if a.shape[0] == 0:
        return a.copy(), 0
    vals, vecs = np.linalg.eigh(a)
    top = float(np.max(vals)) if vals.size else 0.0
    keep = vals > rtol * max(top, 1e-300)
    inv = (vecs[:, keep] / vals[keep]) @ vecs[:, keep].T
    return inv, int(np.count_nonzero(keep))


__all__ = [
    "DIFFUSE_FRACTION",
    "Innovations",
    "Products",
    "filter_products",
    "pinv_sym",
    "run_filter",
]
