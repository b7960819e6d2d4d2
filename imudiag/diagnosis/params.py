"""The 9 diagnosed parameters of a triad and their estimate record.

Order, units (the certificate's, spec/reports.md): biases ``B_x B_y B_z``
(output units), scale-factor errors ``E_x E_y E_z`` (output per input unit),
misalignment differences ``d1 d2 d3`` (rad). Predicates F1..F9 of the paper
are checked on these in this order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..certificate import MISALIGNMENT_PAIRS, SENSOR_NAMES, TriadModel
from .gauge import shape_of_triad

CAUSES = ("bias",) * 3 + ("scale_factor",) * 3 + ("misalignment",) * 3
PARAM_KEYS = ("bias", "scale_factor", "misalignment")


def sensor_of(triad: str, index: int) -> str:
    """Sensor name (``ax``..) or misalignment pair (``ax/ay``..) of parameter ``index``."""
    if index < 6:
        return SENSOR_NAMES[triad][index % 3]
    return MISALIGNMENT_PAIRS[triad][index - 6]


def _grouped(unit: str) -> str:
    """``unit`` in parentheses when it is a quotient (``m/s^2``), as a side of another."""
    return f"({unit})" if "/" in unit else unit


def cause_unit(triad: TriadModel, cause: str) -> str:
    """The unit of a parameter of ``cause`` (spec/reports.md): a bias in the output unit, a
    scale-factor error in output per input unit, a misalignment difference in rad."""
    if cause == "bias":
        return triad.output_unit
    if cause == "scale_factor":  # count/(deg/s), (m/s^2)/(m/s^2), g/g
        out, per = triad.output_unit, triad.input_unit
        return f"{_grouped(out)}/{_grouped(per)}"
    if cause == "misalignment":
        return "rad"
    raise ValueError(f"no unit for cause {cause!r}")


def parameter_units(triad: TriadModel) -> tuple[str, ...]:
    """The unit of each of the 9 parameters in their order (:data:`CAUSES`), for text."""
    return tuple(cause_unit(triad, cause) for cause in CAUSES)


def std_above_limit(std: float, ratio: float, limit: float, unit: str) -> str:
    """The reason a parameter is undetermined: its std above ``ratio`` times its limit,
    both in ``unit`` (the parameter's, :func:`parameter_units`)."""
    return f"std {std:.3g} {unit} above {ratio:g} x limit {limit:.3g} {unit}"


def certificate_std_vector(triad: TriadModel) -> np.ndarray:
    """The std (9,) of the certificate's own (B, E, d) in certificate units: its stated
    ``uncertainty`` (a calibration's), 0 where it states none."""
    if triad.uncertainty is None:
        return np.zeros(9)
    return np.nan_to_num(triad.uncertainty.vector(), nan=0.0)


def certificate_vector(triad: TriadModel) -> np.ndarray:
    """The certificate's (B, E, d) as a (9,) vector in certificate units."""
    return np.concatenate(
        [triad.bias, triad.scale_factor_error, triad.misalignment_differences]
    ).astype(float)


def limit_vector(triad: TriadModel) -> np.ndarray:
    """The limits lambda_1..lambda_9 (9,) in certificate units."""
    lim = triad.limits
    return np.concatenate([lim.bias, lim.scale_factor_error, lim.misalignment]).astype(float)


def internal_scale(triad: TriadModel, magnitude: float) -> np.ndarray:
    """Factors (9,) from the fits' dimensionless parameters to certificate units.

    Fits use beta = B / (S m), e = E / S and d, with m the reference magnitude
    in input units; so B = beta S m, E = e S.
    """
    s = triad.scale_factor
    return np.concatenate([s * magnitude, s, np.ones(3)])


def _frozen(x: np.ndarray) -> np.ndarray:
    x.setflags(write=False)
    return x


@dataclass(frozen=True, eq=False)
class TriadForm:
    """A triad's certificate in the one internal form the fits work in, made once per
    diagnosis (:func:`triad_form`) and passed down to every window's fits instead of the
    :class:`~imudiag.certificate.TriadModel` they would each convert again: the (B, E, d)
    vector, the limits and the certificate's own std (9,) in certificate units, the
    parameters' units, and the gauge (:mod:`.gauge`: the observable shape (6,) of the
    certificate's N = P Q and Q). Its arrays are read-only (they are shared by every fit).
    Every fit taking a ``TriadModel`` also takes its form."""

    model: TriadModel
    certificate: np.ndarray  #: (9,) certificate units
    limit: np.ndarray  #: (9,) certificate units
    certificate_std: np.ndarray  #: (9,) certificate units
    units: tuple[str, ...]  #: the 9 parameters' units (:func:`parameter_units`)
    scale_factor: np.ndarray  #: (3,) output per input unit
    shape: np.ndarray  #: (6,) observable shape of the certificate's N (e_x e_y e_z d1 d2 d3)
    q: np.ndarray  #: (3, 3) rotation of the certificate's N = P Q

    @property
    def name(self) -> str:
        """The triad's name (``accel`` / ``gyro``)."""
        return self.model.name

    def scale(self, magnitude: float) -> np.ndarray:
        """Factors (9,) from the fits' dimensionless parameters to certificate units at
        reference magnitude ``magnitude`` (input units): :func:`internal_scale`."""
        s = self.scale_factor
        return np.concatenate([s * magnitude, s, np.ones(3)])

    def internal(self, magnitude: float) -> np.ndarray:
        """The certificate's dimensionless parameters theta_c (9,) = (B / (S m), shape)."""
        return np.concatenate([self.model.bias / (self.scale_factor * magnitude), self.shape])

    def internal_limits(self, magnitude: float) -> np.ndarray:
        """The limits (9,) in the fits' dimensionless units."""
        return self.limit / self.scale(magnitude)


def triad_form(triad: TriadModel | TriadForm) -> TriadForm:
    """The internal form of ``triad`` (``triad`` itself when it is one already)."""
    if isinstance(triad, TriadForm):
        return triad
    shape, q = shape_of_triad(triad)
    return TriadForm(
        model=triad,
        certificate=_frozen(certificate_vector(triad)),
        limit=_frozen(limit_vector(triad)),
        certificate_std=_frozen(certificate_std_vector(triad)),
        units=parameter_units(triad),
        scale_factor=_frozen(np.asarray(triad.scale_factor, dtype=float).copy()),
        shape=_frozen(shape),
        q=_frozen(q),
    )


def model_of(triad: TriadModel | TriadForm) -> TriadModel:
    """The certificate's triad model behind ``triad`` (a model or its form)."""
    return triad.model if isinstance(triad, TriadForm) else triad


@dataclass
class TriadFit:
    """Estimates of a triad's 9 parameters over one window, in certificate units.

    ``determined[i]`` is true when the window pins parameter i down well
    enough to compare it with its limit (std at most ``determined_std_ratio``
    times the limit); ``reasons[i]`` says why not otherwise. ``judged[i]`` is
    false when the fit behind parameter i had no redundancy to check its noise
    model (effective degrees of freedom below the configured minimum): such a
    parameter is neither determined nor a fault candidate.
    """

    triad: str
    method: str
    estimate: np.ndarray  #: (9,) certificate units
    std: np.ndarray  #: (9,) certificate units (inf where not estimable)
    certificate: np.ndarray  #: (9,)
    limit: np.ndarray  #: (9,)
    determined: np.ndarray  #: (9,) bool
    reasons: list[str] = field(default_factory=lambda: [""] * 9)
    condition: float = float("inf")  #: condition number of the limit-scaled information matrix
    points: int = 0  #: intervals (or samples) used
    rms_residual: float = float("nan")  #: normalised residual RMS, dimensionless
    extra: dict = field(default_factory=dict)
    judged: np.ndarray = field(default_factory=lambda: np.ones(9, dtype=bool))
    dof: float = float("nan")  #: effective degrees of freedom of the fit (observations - params)
    #: factor (>= 1, dimensionless) the fit scaled its covariance by for a residual scatter
    #: beyond its noise (chi^2 / dof, the Birge ratio); 1 where it did not
    cov_scale: float = 1.0
    #: (G, 9) estimate minus certificate with each point (interval or motion) of the fit left
    #: out, certificate units (NaN where that point alone carries the parameter); None when the
    #: fit does not compute it (:mod:`.robust`)
    loo_deviation: np.ndarray | None = None
    #: (G,) robustly standardised deletion residual of each point, sigma (:mod:`.robust`)
    point_z: np.ndarray | None = None
    #: (K,) which of the points given to the fit it kept (outliers rejected: False)
    kept: np.ndarray | None = None
    #: scatter of the fit beyond its points' noise (normalised residual variance, 0: none)
    excess_var: float = 0.0
    #: names of the points behind ``loo_deviation`` rows, for reports
    point_labels: list[str] | None = None
    #: (9,) std of the certificate's own values (:func:`certificate_std_vector`), certificate
    #: units: 0 unless the certificate states an ``uncertainty`` (a calibration's)
    certificate_std: np.ndarray = field(default_factory=lambda: np.zeros(9))
    #: (9,) the part of ``std``^2 the fit estimated from its own residual scatter (its excess
    #: variance and Birge ratio, estimated with :attr:`dof` degrees of freedom), certificate
    #: units^2; 0 where the std rests on the points' stated noise alone
    estimated_var: np.ndarray = field(default_factory=lambda: np.zeros(9))
    #: (9,) the degrees of freedom ``estimated_var`` was measured with, where a parameter's
    #: differ from the fit's :attr:`dof` (the MEMS gyro's rest biases: intervals - 1); NaN:
    #: :attr:`dof`
    estimated_dof: np.ndarray = field(default_factory=lambda: np.full(9, np.nan))

    def require_redundancy(self, dof: float, min_dof: float, idx: range, what: str) -> None:
        """Mark parameters ``idx`` unjudged when the fit's effective dof is below ``min_dof``."""
        if dof >= min_dof:
            return
        for i in idx:
            self.judged[i] = False
            if self.determined[i]:
                self.determined[i] = False
                self.reasons[i] = (
                    f"no redundancy to check the fit: {what} for the parameters it "
                    f"determines ({dof:.1f} degrees of freedom, {min_dof:g} needed)"
                )

    @property
    def deviation(self) -> np.ndarray:
        """Estimate minus certificate (9,), certificate units."""
        return self.estimate - self.certificate

    @property
    def deviation_std(self) -> np.ndarray:
        """Std (9,) of :attr:`deviation`, certificate units: the estimate's and the
        certificate's own (:attr:`certificate_std`) combined, sqrt(std^2 + cert_std^2)."""
        return np.hypot(self.std, self.certificate_std)

    @property
    def deviation_dof(self) -> np.ndarray:
        """Effective degrees of freedom (9,) of :attr:`deviation_std` (Welch-Satterthwaite):
        dof (std^2 + cert_std^2)^2 / estimated_var^2 (dof: :attr:`estimated_dof`, else
        :attr:`dof`), infinite where no part of it was
        estimated. A deviation over its std is Student-t with these degrees of freedom,
        not normal, when the std holds a scatter measured on few points."""
        total = self.std**2 + self.certificate_std**2
        est = self.estimated_var
        dof = np.where(np.isfinite(self.estimated_dof), self.estimated_dof, self.dof)
        out = np.full(9, np.inf)
        use = (est > 0) & np.isfinite(total) & np.isfinite(dof)
        out[use] = np.maximum(dof[use], 0.0) * total[use] ** 2 / est[use] ** 2
        return out

    def to_json(self) -> dict:
        """Estimates and standard deviations grouped by cause (non-finite values as null)."""

        def clean(v: np.ndarray) -> list:
            return [x if math.isfinite(x) else None for x in np.asarray(v, dtype=float).tolist()]

        out: dict = {"method": self.method, "points": int(self.points)}
        estimate, std = clean(self.estimate), clean(self.std)
        determined = [bool(x) for x in np.asarray(self.determined).tolist()]
        for k, key in enumerate(PARAM_KEYS):
            sl = slice(3 * k, 3 * k + 3)
            out[key] = {"estimate": estimate[sl], "std": std[sl], "determined": determined[sl]}
        out["condition"] = float(self.condition) if np.isfinite(self.condition) else None
        out["dof"] = float(self.dof) if np.isfinite(self.dof) else None
        out["rms_residual"] = float(self.rms_residual) if np.isfinite(self.rms_residual) else None
        out.update(self.extra)
        return out


def undetermined_fit(triad: TriadModel | TriadForm, method: str, reason: str) -> TriadFit:
    """A fit where nothing could be estimated, for ``reason``."""
    form = triad_form(triad)
    return TriadFit(
        triad=form.name,
        method=method,
        estimate=form.certificate.copy(),
        std=np.full(9, np.inf),
        certificate=form.certificate,
        limit=form.limit,
        determined=np.zeros(9, dtype=bool),
        reasons=[reason] * 9,
        certificate_std=form.certificate_std,
    )


__all__ = [
    "CAUSES",
    "PARAM_KEYS",
    "TriadFit",
    "TriadForm",
    "certificate_std_vector",
    "model_of",
    "triad_form",
    "certificate_vector",
    "limit_vector",
    "internal_scale",
    "sensor_of",
    "undetermined_fit",
]
