"""CPU work beside the model: the measures of an image run in threads while the next image is
predicted.

Boundary IoU, the calibration sums and a pair's cross-view sums are OpenCV, numpy and torch
passes that release the GIL; run in threads they overlap the model's forward passes (on a GPU,
the whole of them). At most ``2 × threads`` jobs wait at a time, so the full-size label images and
confidences they hold stay a bounded handful.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any


class Background:
    """Jobs run in ``threads`` threads (0: at once, in the caller's thread).

    Use as a context manager: leaving it waits for every job (and joins the threads, also when
    an error leaves the block).
    """

    def __init__(self, threads: int) -> None:
        self.pool = ThreadPoolExecutor(threads) if threads > 0 else None
        self.limit = 2 * max(1, threads)
        self.running: deque[Future[Any]] = deque()

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future[Any]:
        """Run ``fn(*args)``; its future (done already without threads). Waits first for the
        oldest job while too many are running (its error, if any, is raised there)."""
        if self.pool is None:
            done: Future[Any] = Future()
            done.set_result(fn(*args))
            return done
        while len(self.running) >= self.limit:
            self.running.popleft().result()
        future = self.pool.submit(fn, *args)
        self.running.append(future)
        return future

    def __enter__(self) -> Background:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=exc[0] is not None)
