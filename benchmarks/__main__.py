"""``python -m benchmarks``: run the benchmark set (see benchmarks/run.py)."""

import sys

from .run import main

sys.exit(main())
