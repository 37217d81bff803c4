"""Debounced re-runs on the pipeline's thread pool, and the memory they free handed back.

After a change, one re-run thread waits until changes stop for `debounce_s` (at most `max_wait_s`),
then asks its owner for the jobs of a re-run (`plan`) and runs them on the pool; the owner's jobs
skip what a newer change made pointless, so a slider storm costs one or two runs, not one per
change. Work outside the debounce (a new image) is `submit`ted and counted as in flight.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed

import cv2

from signpose.pipeline.evaluate import CORES, release_freed_memory

# The memory freed by deletions and finished work goes back to the system this long after (by
# then the requests that deleted images have let go of them), once for a burst.
TRIM_DELAY_S = 1.0

Job = Callable[[], None]


def share_cores(workers: int) -> int:
    """Set OpenCV's thread count, process-wide, for `workers` pipeline threads; the count it had.

    The pool's threads already share the cores; OpenCV's own threads inside each only compete with
    them (2 cores, 200 images re-run by 2 workers: 2.33 s with one OpenCV thread each, 2.65 s with
    two). One worker keeps OpenCV's threads. Called where the process starts, as it changes the
    whole process."""
    before = cv2.getNumThreads()
    if workers > 1:
        cv2.setNumThreads(max(1, CORES // workers))
    return before


class Rerunner:
    """The re-run thread and the count of pipeline work going on.

    `_lock` (and the condition `_idle` on it) guards `_dirty`, `_first_change`, `_last_change`,
    `_batch_running`, `_in_flight`, `_closed` and `_trim_timer`. Callers may hold their own locks
    while calling `request` and `submit`; the runner never holds `_lock` while it calls out (`plan`,
    `on_progress`, the jobs), so locks are always taken theirs first.
    """

    def __init__(self, pool: ThreadPoolExecutor, *, debounce_s: float, max_wait_s: float,
                 plan: Callable[[], list[Job]], on_progress: Callable[[], None]) -> None:
        """`plan()`: the jobs of one re-run, called in the re-run thread once changes settle (it may do work
        they share first); `on_progress()`: called after each job and each re-run ends."""
        self._pool = pool
        self._debounce_s, self._max_wait_s = debounce_s, max_wait_s
        self._plan, self._on_progress = plan, on_progress
        self._lock = threading.Lock()
        self._idle = threading.Condition(self._lock)
        self._dirty = False
        self._first_change = self._last_change = 0.0
        self._batch_running = False
        self._in_flight = 0
        self._closed = False
        self._trim_timer: threading.Timer | None = None
        self._thread = threading.Thread(target=self._loop, name="signpose-rerun", daemon=True)
        self._thread.start()

    @property
    def busy(self) -> bool:
        """Whether any job is running or a re-run is due (advisory: read without the lock)."""
        return self._dirty or self._batch_running or self._in_flight > 0

    @property
    def closed(self) -> bool:
        return self._closed

    def wait_idle(self, timeout: float) -> bool:
        """Block until nothing is running or due (True) or `timeout` seconds pass (False)."""
        with self._idle:
            return self._idle.wait_for(lambda: not self.busy, timeout)

    def request(self) -> None:
        """Something changed: re-run once changes settle."""
        with self._lock:
            now = time.monotonic()
            if not self._dirty:
                self._first_change = now
            self._dirty = True
            self._last_change = now
            self._idle.notify_all()

    def submit(self, job: Job) -> None:
        """Run `job` on the pool now, outside the debounce; busy until it ends."""
        with self._lock:
            self._in_flight += 1
        self._pool.submit(self._run_now, job)

    def _run_now(self, job: Job) -> None:
        try:
            job()
        finally:
            with self._lock:
                self._in_flight -= 1
                self._idle.notify_all()
            self._on_progress()
            self.trim_soon()

    def _loop(self) -> None:
        while True:
            with self._idle:
                self._idle.wait_for(lambda: self._dirty or self._closed)
                if self._closed:
                    return
                # Debounce: wait for a quiet spell, but not past max_wait_s, so a long slider
                # drag still shows intermediate results.
                while not self._closed:
                    due = min(self._last_change + self._debounce_s, self._first_change + self._max_wait_s)
                    if time.monotonic() >= due:
                        break
                    self._idle.wait(due - time.monotonic())
                self._dirty = False
                self._batch_running = True
            try:
                # The jobs are not kept while the loop waits for the next change: images deleted
                # meanwhile would stay in memory until then.
                self._run_batch(self._plan())
            finally:
                with self._lock:
                    self._batch_running = False
                    self._idle.notify_all()
                self._on_progress()
                self.trim_soon()

    def _run_batch(self, jobs: list[Job]) -> None:
        futures = [self._pool.submit(job) for job in jobs]
        for future in as_completed(futures):
            future.result()
            self._on_progress()

    def trim_soon(self) -> None:
        """Hand the memory freed by deletions and finished work back to the system TRIM_DELAY_S from
        now, unless work is still going on then (its end calls this again). glibc would keep it
        (`release_freed_memory`): a server stayed at 3.7 GB after deleting all its photos."""
        with self._lock:
            if self._trim_timer is None and not self._closed:
                self._trim_timer = threading.Timer(TRIM_DELAY_S, self._trim)
                self._trim_timer.daemon = True
                self._trim_timer.start()

    def _trim(self) -> None:
        with self._lock:
            self._trim_timer = None
            if self.busy or self._closed:
                return
        release_freed_memory()

    def close(self) -> None:
        """Stop the re-run thread (after the re-run going on) and any trim due; the pool is its owner's."""
        with self._lock:
            self._closed = True
            self._idle.notify_all()
            if self._trim_timer is not None:
                self._trim_timer.cancel()
        self._thread.join(timeout=10)
