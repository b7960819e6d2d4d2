"""Model check: what the certificate's linear white-noise model gets wrong on a measured
session, the named cause, the extended model and its gain on held-out data
(spec/reports.md, ``imudiag model-check``).

``model_check(log, certificate, seed=0, config=None) -> ModelCheckResult`` with
``.report`` (the ``imudiag-model-check/1`` document), ``.effects`` and
``.extended`` (the certificate with the fitted extended-model blocks).
"""

from .check import CATALOGUE, FORMAT, ModelCheckResult, model_check
from .config import ModelCheckConfig

__all__ = ["CATALOGUE", "FORMAT", "ModelCheckConfig", "ModelCheckResult", "model_check"]
