"""``python -m imudiag`` is the ``imudiag`` command."""

import sys

from .cli import main

sys.exit(main())
