"""The fleet's job feed (imudiag/fleet/feed.py): logs hashed in a thread, largest first, each
submitted once hashed and once the client is up; items made before the client kept, in
order; the thread's error raised again in the consumer's thread; a close stops it after the
item it is making. Threads coordinated by events, never by a clock."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from imudiag.fleet.feed import Feed

WAIT_S = 60.0  # an upper bound for a thread's step on a loaded machine, never reached


def test_items_made_before_the_client_are_kept_and_all_are_submitted_in_order() -> None:
    made_three = threading.Event()
    go_on = threading.Event()

    def produce() -> Iterator[int]:
        yield from (1, 2, 3)
        made_three.set()
        assert go_on.wait(WAIT_S)
        yield from (4, 5)

    feed: Feed[int] = Feed(produce).start()
    assert made_three.wait(WAIT_S)
    submitted: list[int] = []
    feed.attach(submitted.append)  # 1-3 kept until now, submitted here in order
    assert submitted == [1, 2, 3]
    go_on.set()
    assert feed.ended.wait(WAIT_S)
    feed.close()
    feed.check()
    assert submitted == [1, 2, 3, 4, 5]
    assert feed.more.is_set()


def test_a_consumer_waiting_for_more_is_woken_by_each_item_and_by_the_end() -> None:
    step = threading.Semaphore(0)

    def produce() -> Iterator[str]:
        for name in ("a", "b"):
            assert step.acquire(timeout=WAIT_S)
            yield name

    submitted: list[str] = []
    feed: Feed[str] = Feed(produce).start()
    feed.attach(submitted.append)
    for expected in (["a"], ["a", "b"]):
        feed.more.clear()
        step.release()
        assert feed.more.wait(WAIT_S)  # set once the item is submitted
        assert submitted == expected
    assert feed.ended.wait(WAIT_S)
    assert submitted == ["a", "b"]
    feed.close()


def test_the_threads_error_is_raised_again_by_the_consumer() -> None:
    def produce() -> Iterator[int]:
        yield 1
        raise PermissionError("flight-002.bin: cannot read")

    feed: Feed[int] = Feed(produce).start()
    assert feed.ended.wait(WAIT_S)
    submitted: list[int] = []
    feed.attach(submitted.append)
    assert submitted == [1]
    with pytest.raises(PermissionError, match="flight-002.bin"):
        feed.check()
    feed.close()


def test_a_close_stops_the_thread_after_the_item_it_is_making() -> None:
    making = threading.Event()
    release = threading.Event()
    seen: list[int] = []

    def produce() -> Iterator[int]:
        for i in range(1000):
            seen.append(i)
            if i == 2:
                making.set()
                assert release.wait(WAIT_S)
            yield i

    feed: Feed[int] = Feed(produce).start()
    assert making.wait(WAIT_S)
    closer = threading.Thread(target=feed.close)
    closer.start()
    release.set()
    closer.join(WAIT_S)
    assert not closer.is_alive() and feed.ended.is_set()
    assert seen == [0, 1, 2]  # the item being made, then no more
    submitted: list[int] = []
    feed.attach(submitted.append)
    assert submitted == [0, 1]  # the item made after the stop is dropped
