"""Optional compiled kernels of the window fits (numba, the ``fleet`` extra; issue 28).

The exact fit (:func:`.scalar_fit.exact_fit`) runs a small damped Gauss-Newton loop once or
more per window and per outlier probe: 10-50 interval means, 9 parameters, 10-30 cost
evaluations, each a handful of numpy calls on arrays of a few hundred numbers, so numpy's
per-call overhead is most of its CPU. :func:`exact_gauss_newton` is the same loop compiled by
numba: the same residuals, weights, cost, Jacobian, damping, step control and stopping rule,
in the same order. Its 9x9 damped normal equations are solved by Gaussian elimination with
partial pivoting on the Jacobi-scaled matrix instead of LAPACK's SVD least squares
(``np.linalg.lstsq``), so its floats differ from the plain loop's by rounding. Where that
elimination breaks down (no pivot, or one below :data:`.numba_kernels.PIVOT_RATIO` of the
largest: singular even after the damping, or not numbers) the kernel gives up and the plain
loop runs the fit instead. ``tests/test_fit_kernels.py`` holds the two to each other, and
whole reports made with the kernels to the frozen ones within the cross-processor tolerance
(the rounding of a near-singular window differs there as between processors).

The gyro rotation fit evaluates each motion's rotation and its sensitivity to N^-1
(:func:`imudiag.rotations.segmented_product_sensitivity`, a pairwise product tree in numpy)
once per try; :func:`product_sensitivity` is the same figures compiled, the products taken
along each motion in order, so again equal to rounding; so are N^-1 and its derivatives
(:func:`ninv_derivatives`) and the predicted directions with theirs
(:func:`predict_directions`).

The kernels themselves are in :mod:`.numba_kernels` (module-level, so numba's disk cache
serves every later process: about 1 s of CPU to load them against 11 s to compile). The
plain numpy paths stay the reference and the default. :func:`enable` switches the kernel
on in this process where numba is installed, :func:`switched` in one thread for a block: a
fleet task runs its diagnosis inside ``switched(True)`` (the JIT compile, or the load of
numba's on-disk cache, paid once by the worker's first task in its warm-up, outside that
log's CPU figure, :func:`load`), so a process that calls the task itself keeps its own
choice; ``imudiag diagnose`` and the daemon keep the plain loop unless
``IMUDIAG_KERNELS=numba`` is set in the environment.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

#: "on": None until the first :func:`enabled` reads ``IMUDIAG_KERNELS``
_STATE: dict[str, Any] = {"on": None, "kernel": None, "error": None}
#: the compiled functions by name (``exact_gauss_newton``, ``product_sensitivity``,
#: ``ninv_derivatives``, ``predict``)
_KERNELS: dict[str, Callable[..., Any]] = {}


def available() -> bool:
    """Whether numba can be imported here (the ``fleet`` extra installs it)."""
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


def load() -> bool:
    """Compile the kernels (or load them from numba's cache) and run each once, without
    switching them on; whether they can be used (without numba, or when that failed,
    :func:`status` says why). Cheap after the first call."""
    if _STATE["kernel"] is None and _STATE["error"] is None:
        try:
            _KERNELS.update(_compile())
            _STATE["kernel"] = _KERNELS["exact_gauss_newton"]
        except Exception as exc:  # noqa: BLE001 - no numba, or a failed compile: plain loops
            _STATE["error"] = f"{type(exc).__name__}: {exc}"
    return _STATE["kernel"] is not None


def enable(on: bool = True) -> bool:
    """Use the compiled kernels in this process from now on (``on``, after :func:`load`), or
    the plain loops; returns whether the kernels are in use."""
    _STATE["on"] = bool(on) and load()
    return bool(_STATE["on"])


#: a thread's own choice (:func:`switched`), over the process's
_LOCAL = threading.local()


@contextlib.contextmanager
def switched(on: bool) -> Iterator[bool]:
    """The kernels on (where :func:`load` can) or off in this thread for the ``with`` block,
    whatever the process's choice, restored after (a fleet task: the caller's process and
    other tasks' threads keep theirs); yields whether they are on."""
    before = getattr(_LOCAL, "on", None)
    _LOCAL.on = bool(on) and load()
    try:
        yield _LOCAL.on
    finally:
        _LOCAL.on = before


def enabled() -> bool:
    """Whether the compiled kernels are in use in this thread: its :func:`switched` block,
    else the process's :func:`enable` (the first call switches them on when
    ``IMUDIAG_KERNELS=numba`` is set in the environment)."""
    local = getattr(_LOCAL, "on", None)
    if local is not None:
        return bool(local)
    if _STATE["on"] is None:
        _STATE["on"] = False
        if os.environ.get("IMUDIAG_KERNELS", "").strip().lower() == "numba":
            enable(True)
    return bool(_STATE["on"])


def status() -> str:
    """``numba`` when the kernels are in use, else ``plain`` and why."""
    if enabled():
        return "numba"
    return "plain" + (f" ({_STATE['error']})" if _STATE["error"] else "")


def exact_gauss_newton(
    theta: np.ndarray,
    extra: float,
    v: np.ndarray,
    mu: np.ndarray,
    var_v: np.ndarray,
    prior_prec: np.ndarray,
    theta_c: np.ndarray,
    max_iter: int,
    max_shape: float,
    floor2: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The exact fit's damped Gauss-Newton loop, compiled: (theta (9,), residuals (K,),
    Jacobian (K, 9), residual variances (K,)), all in the fit's dimensionless units, as the
    plain loop of :func:`.scalar_fit.exact_fit`; None when the kernels are off or a solve was
    ill-conditioned (the caller runs the plain loop)."""
    kernel: Callable[..., Any] | None = _STATE["kernel"] if enabled() else None
    if kernel is None:
        return None
    ok, th, r, jac, sig2 = kernel(
        np.ascontiguousarray(theta, dtype=float),
        float(extra),
        np.ascontiguousarray(v, dtype=float),
        np.ascontiguousarray(mu, dtype=float),
        np.ascontiguousarray(var_v, dtype=float),
        np.ascontiguousarray(prior_prec, dtype=float),
        np.ascontiguousarray(theta_c, dtype=float),
        int(max_iter),
        float(max_shape),
        float(floor2),
    )
    if not ok:
        return None
    return th, r, jac, sig2


def product_sensitivity(
    theta: np.ndarray, inc: np.ndarray, lengths: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`imudiag.rotations.segmented_product_sensitivity` compiled: the ordered products
    (S, 4) of the rotation vectors ``theta`` (K, 3), rad, by segment of ``lengths`` (S,), and
    their sensitivity (S, 3, 3, 3) to L where ``theta = L inc``; None when the kernels are
    off. Each segment's product is taken left to right and its suffixes right to left (the
    plain path multiplies pairwise up and down a tree): equal to rounding."""
    if not enabled():
        return None
    q, sens = _KERNELS["product_sensitivity"](
        np.ascontiguousarray(theta, dtype=float),
        np.ascontiguousarray(inc, dtype=float),
        np.ascontiguousarray(lengths, dtype=np.int64),
    )
    return q, sens.reshape(-1, 3, 3, 3)


def ninv_derivatives(
    shape_c: np.ndarray, q_c: np.ndarray, x: np.ndarray, fit_frame: bool
) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`.gyro_fit.ninv_derivatives` compiled (N^-1 (3, 3) and its derivatives (npar,
    3, 3) per parameter unit); None when the kernels are off."""
    if not enabled():
        return None
    out: tuple[np.ndarray, np.ndarray] = _KERNELS["ninv_derivatives"](
        np.ascontiguousarray(shape_c, dtype=float),
        np.ascontiguousarray(q_c, dtype=float),
        np.ascontiguousarray(x, dtype=float),
        bool(fit_frame),
    )
    return out


def predict_directions(
    q: np.ndarray, sens: np.ndarray, dninv: np.ndarray, up0: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """The rotation fit's predicted end directions (n, 3) and their derivatives (n, 3, m)
    from the motions' rotations ``q`` (n, 4), sensitivities ``sens`` (n, 3, 3, 3), dN^-1
    (m, 3, 3) and start directions ``up0`` (n, 3), compiled; None when the kernels are off."""
    if not enabled():
        return None
    out: tuple[np.ndarray, np.ndarray] = _KERNELS["predict"](
        np.ascontiguousarray(q, dtype=float),
        np.ascontiguousarray(sens, dtype=float),
        np.ascontiguousarray(dninv, dtype=float),
        np.ascontiguousarray(up0, dtype=float),
    )
    return out


def _compile() -> dict[str, Callable[..., Any]]:
    """The numba kernels by name, compiled (or loaded from numba's cache) and each run once."""
    from . import numba_kernels

    return numba_kernels.warm_up()
