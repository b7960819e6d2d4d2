"""The logs of a fleet run fed to Dask as they are hashed: one thread reads each log's content
hash (the key that lets a run resume) largest log first, and submits its task as soon as the
hash is known and the client is up. The workers start on the largest logs while the others
are still read; the client no longer hashes the whole fleet (1.5 GB/s) before the first task.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from typing import Generic, TypeVar

T = TypeVar("T")


class Feed(Generic[T]):
    """Items of ``produce()`` (an iterator run in a thread of its own), handed in order to
    ``submit`` once :meth:`attach` has given one; those made before are kept until then.

    :attr:`more` is set after each item submitted and when the thread ends: a consumer that
    clears it, finds nothing to do and sees :attr:`ended` unset can wait on it. An exception
    of ``produce`` is raised again by :meth:`check`. :meth:`close` stops the thread after the
    item it is making and waits for it."""

    def __init__(self, produce: Callable[[], Iterator[T]]) -> None:
        self._produce = produce
        self._lock = threading.Lock()
        self._submit: Callable[[T], object] | None = None
        self._kept: list[T] = []
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self.more = threading.Event()
        self.ended = threading.Event()
        self._thread = threading.Thread(target=self._run, name="imudiag-fleet-feed", daemon=True)

    def start(self) -> Feed[T]:
        """Start the thread; this feed."""
        self._thread.start()
        return self

    def _run(self) -> None:
        try:
            for item in self._produce():
                if self._stop.is_set():
                    return
                with self._lock:
                    submit = self._submit
                    if submit is None:
                        self._kept.append(item)
                        continue
                submit(item)
                self.more.set()
        except BaseException as exc:  # noqa: BLE001 - raised again in the consumer's thread
            self._error = exc
        finally:
            self.ended.set()
            self.more.set()

    def attach(self, submit: Callable[[T], object]) -> None:
        """Submit the items kept so far, in order, then each new one as it is made."""
        while True:
            with self._lock:
                kept, self._kept = self._kept, []
                if not kept:
                    self._submit = submit
                    return
            for item in kept:  # outside the lock: the thread keeps the next ones meanwhile
                submit(item)
            self.more.set()

    def check(self) -> None:
        """Raise again the exception that ended the thread, if one did."""
        if self._error is not None:
            raise self._error

    def close(self) -> None:
        """Stop making items (after the current one) and wait for the thread."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()


__all__ = ["Feed"]
