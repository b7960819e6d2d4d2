"""Preloaded by the forkserver a local cluster's workers are forked from
(:data:`imudiag.fleet.runner.FORKSERVER_PRELOAD`): importing this module loads what every
fleet worker keeps (:func:`.task.preload`: the diagnosis' modules, the compiled kernels,
pyarrow's CSV reader; no thread started) once, in the server, then freezes it (``gc.freeze``,
so that no collection in a worker writes to the pages it shares with the server and the
other workers)."""

import gc

from .task import preload

preload()
gc.freeze()
