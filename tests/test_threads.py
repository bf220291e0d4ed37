"""The diagnosis's independent pieces of work on the threads of the process."""

from __future__ import annotations

import threading
import time

import pytest

from sweep.diagnose.threads import map_threads


def test_map_threads_keeps_the_order_and_runs_side_by_side():
    seen: set[str] = set()

    def work(i: int) -> int:
        seen.add(threading.current_thread().name)
        time.sleep(0.02 * (5 - i))  # the first items end last
        return i * i

    assert map_threads(work, range(5), threads=2) == [0, 1, 4, 9, 16]
    assert len(seen) == 2
    seen.clear()
    assert map_threads(work, range(3), threads=1) == [0, 1, 4]
    assert seen == {threading.current_thread().name}  # one thread: in the caller's
    assert map_threads(work, [], threads=2) == []


def test_map_threads_raises_the_first_failed_items_error_after_the_others_end():
    ended: list[int] = []

    def work(i: int) -> int:
        if i in (1, 3):
            raise ValueError(f"item {i}")
        time.sleep(0.05)
        ended.append(i)
        return i

    with pytest.raises(ValueError, match="item 1"):
        map_threads(work, range(5), threads=2)
    assert sorted(ended) == [0, 2, 4]
