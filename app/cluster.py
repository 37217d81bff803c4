"""Chunks of work on a Dask cluster (`--dask ADDRESS`): connect, share the library once, submit, collect.

Imported only when a command is given `--dask`: without it no Dask module is loaded. The work itself
(`signpose.app.batch`'s chunk functions) is plain Python that every worker imports; signpose must be
installed on the workers, in the version the client runs.
"""

from __future__ import annotations

import socket
from collections import Counter
from collections.abc import Callable, Hashable, Iterable, Iterator
from typing import Any

from signpose.app.batch import EXTRA, BatchError, Chunk

try:
    from distributed import Client, Future, KilledWorker, as_completed
except ImportError as exc:  # Dask is an optional extra
    raise BatchError(f"--dask needs Dask's distributed scheduler: pip install '{EXTRA}' ({exc})") from None

# Times a chunk is run again after it raised (a worker lost mid-chunk is rerun by the scheduler anyway, up to
# its `distributed.scheduler.allowed-failures`, 3 by default).
RETRIES = 2
CONNECT_TIMEOUT_S = 10
# Chunks in flight per worker thread: one running and one waiting, so a worker never waits for the client.
IN_FLIGHT_PER_THREAD = 2


def connect(address: str) -> Client:
    """A client of the Dask scheduler at `address` (tcp://host:8786); BatchError when it cannot be reached."""
    advice = "start one with `dask scheduler` and its workers with `dask worker ADDRESS` (docs/cluster.md)"
    try:
        probe_tcp(address)
        return Client(address, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError) as exc:
        raise BatchError(f"cannot reach the Dask scheduler at {address} ({exc}); {advice}") from None


def probe_tcp(address: str) -> None:
    """OSError at once when nothing listens at the tcp:// (or scheme-less) `address`: Dask's client would try
    again until its timeout before saying so."""
    scheme, _, rest = address.rpartition("://")
    if scheme not in ("", "tcp"):
        return
    host, _, port = rest.rpartition(":")
    if port.isdigit():
        socket.create_connection((host.strip("[]") or "127.0.0.1", int(port)), timeout=CONNECT_TIMEOUT_S).close()


class DaskRunner:
    """Runs chunks on the cluster of `client`, counting those the cluster ran more than once."""

    def __init__(self, client: Client) -> None:
        self.client = client
        self._keys: dict[Hashable, str] = {}  # a submitted task's key: the chunk's name

    @property
    def slots(self) -> int:
        """The cluster's worker threads now: workers may join or leave during a run."""
        return sum(self.client.nthreads().values()) or 1

    def share(self, value: Any) -> Future:
        """`value` sent once to every worker (the library with its features, a flight's files): a future that the
        chunks name. Every worker holds it, so a worker lost takes no shared value with it."""
        return self.client.scatter([value], broadcast=True, hash=False)[0]  # a list's items would each be one

    def run(self, function: Callable[..., Any], shared: tuple, chunks: Iterable[Chunk]) -> Iterator[tuple[Chunk, Any]]:
        """(chunk, `function(*shared, chunk.work)`) for every chunk, as each finishes. Chunks are submitted as
        workers take them, never more than `IN_FLIGHT_PER_THREAD` a thread: the images' bytes of a long run
        stay on disk until their turn."""
        threads = self.slots
        pending = iter(chunks)
        running: dict[Future, Chunk] = {}
        finished = as_completed()

        def submit() -> None:
            while len(running) < IN_FLIGHT_PER_THREAD * threads and (chunk := next(pending, None)) is not None:
                future = self.client.submit(function, *shared, chunk.work, retries=RETRIES, pure=False)
                self._keys[future.key] = chunk.name
                running[future] = chunk
                finished.add(future)

        submit()
        for future in finished:
            chunk = running.pop(future)
            try:
                result = future.result()
            except KilledWorker:
                raise BatchError(f"{chunk.name}: every worker that ran it died (out of memory?); see the workers' "
                                 "logs") from None
            future.release()  # its result is here: a worker lost now must not compute it again
            submit()
            yield chunk, result

    def retried(self) -> list[str]:
        """The chunks the cluster ran more than once (a worker lost while running it, or an error retried)."""
        story = self.client.story(*self._keys)
        started = Counter(entry[1] for entry in story if entry[0] == "scheduler" and entry[3] == "processing")
        return [name for key, name in self._keys.items() if started[key] > 1]

    def close(self) -> None:
        self.client.close()
