"""Two eyes' renders at once: the right eye's on a worker thread of its own while the caller
renders the left.

A simulated frame is mostly work that releases the GIL (the compiled ray cast, OpenCV's
remap and JPEG, numpy's noise and arithmetic on whole images), so on an idle machine with
two cores the pair takes little more than one eye. On a busy one (a sweep with a worker per
core) the two threads only contend, which is why it is a choice and not the default.
"""
from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Generic, TypeVar

T = TypeVar("T")


class EyePair(Generic[T]):
    """`render(left, right)`: both results, the right computed on this object's worker thread
    (named `name`) when `parallel`, else both on the caller's thread. One pair at a time; a
    context manager, close() idempotent."""

    def __init__(self, parallel: bool, name: str = "sim-render-right") -> None:
        self.parallel = parallel
        self._pool: ThreadPoolExecutor | None = (
            ThreadPoolExecutor(max_workers=1, thread_name_prefix=name) if parallel else None)
        self._lock = threading.Lock()

    def render(self, left: Callable[[], T], right: Callable[[], T]) -> tuple[T, T]:
        with self._lock:
            pool = self._pool
            if pool is None:
                return left(), right()
            future = pool.submit(right)
            try:
                first = left()
            finally:
                second = future.result()  # the worker is free again before an error goes up
            return first, second

    def close(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True)

    def __enter__(self) -> "EyePair[T]":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
