"""``python -m fuzz``: bounded-time fuzzing (see fuzz/run.py)."""

import sys

from .run import main

sys.exit(main())
