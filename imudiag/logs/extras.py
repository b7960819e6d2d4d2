"""Optional dependencies of the log readers: a missing one is exit 2 with the pip command."""

from __future__ import annotations

import importlib
from types import ModuleType

from ..errors import BadInput


class MissingExtra(BadInput):
    """A reader's library is not installed; the message gives the exact pip command."""


def require(module: str, extra: str, what: str) -> ModuleType:
    """Import ``module`` or raise :class:`MissingExtra` naming ``pip install 'imudiag[extra]'``."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingExtra(
            f"reading {what} needs the Python package {module.split('.')[0]!r}, "
            f"not installed: pip install 'imudiag[{extra}]'"
        ) from None
