"""The queue that heavy requests wait in: sweeps, single-image recognition, threshold calibration,
chessboard calibration runs, flight exports and map builds (docs/security.md lists the routes).

Each of those holds a thread for seconds to minutes. Run in the AnyIO thread pool that serves
every plain `def` route, a few dozen of them at once (another site's page firing `<img>` tags at a
sweep is enough) left `/api/health`, the settings and the images waiting behind them. Here they
run in threads of their own, at most `workers` at once (the cores: more would only share them),
with at most `max_waiting` more waiting their turn; beyond that a request is answered at once
with 503, a Retry-After header and "busy: N requests queued; try again in a moment".
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TypeVar

import anyio
from fastapi import HTTPException, status

T = TypeVar("T")

RETRY_AFTER_S = 5  # what a busy answer tells the client to wait: about a recognition's time
WAITING_PER_WORKER = 4  # a client waits behind at most this many requests per worker


class WorkQueue:
    """Heavy work in threads of its own (see the module docstring); one per app."""

    def __init__(self, *, workers: int, max_waiting: int | None = None) -> None:
        """`workers` at once (the server's --workers, the cores by default); `max_waiting` more
        waiting, by default WAITING_PER_WORKER per worker."""
        self.workers = workers
        self.max_waiting = WAITING_PER_WORKER * workers if max_waiting is None else max_waiting
        self._turns = anyio.CapacityLimiter(workers)
        # The threads' own: a thread takes a token for the task that starts it, and a task cannot
        # hold two tokens of one limiter. Never the AnyIO default limiter of the `def` routes.
        self._threads = anyio.CapacityLimiter(workers)

    @property
    def queued(self) -> int:
        """Requests running or waiting their turn."""
        stats = self._turns.statistics()
        return stats.borrowed_tokens + stats.tasks_waiting

    async def run(self, what: str, work: Callable[[threading.Event], T], *, limit_s: float | None) -> T:
        """`work(stop)` in a thread of the queue once its turn comes; 503 "busy" at once when
        `max_waiting` requests wait already, 503 once it runs past `limit_s` (None: no limit).

        Past the limit the request is answered, the thread abandoned, and `stop` set so that work
        able to end early (a sweep between runs) does.
        """
        if self._turns.statistics().tasks_waiting >= self.max_waiting:
            raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE,
                                f"busy: {self.queued} requests queued; try again in a moment",
                                headers={"Retry-After": str(RETRY_AFTER_S)})
        stop = threading.Event()
        async with self._turns:  # the time limit counts from the work's start, not from the queue's
            try:
                with anyio.fail_after(limit_s):
                    return await anyio.to_thread.run_sync(work, stop, abandon_on_cancel=True, limiter=self._threads)
            except TimeoutError:
                stop.set()
                raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE,
                                    f"{what} took longer than the {limit_s:g} s limit (signpose serve "
                                    "--request-timeout); try fewer images or steps, or lighter settings") from None
