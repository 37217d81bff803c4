"""The stages of `recognize`, the settings each reads, and a runner that times and caches them.

Every field of `Settings` names the stages it feeds in its metadata ("stages"). A cached stage's
results are keyed by `stage_key`: the values of every setting that feeds it or a cached stage whose
results it reads. A setting added to `Settings` therefore reaches the keys of the stages it names,
and one that no cached stage reads says so by naming only stages that run every time.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from .settings import Settings

T = TypeVar("T")

# What `Recognition.timing_ms` reports, in this order: each cached stage's time counts in one of them.
STAGES = ("segment", "features", "match", "ransac", "pose")


@dataclass(frozen=True)
class CachedStage:
    """A step of `recognize` whose results a `StageCache` keeps.

    reads: the cached stages whose results its inputs come from, so whose settings its key holds
    too; timed_as: the entry of STAGES its time counts in; reported: whether a cache hit marks
    that entry reused (not where the rest of the entry's work runs every time).
    """

    reads: tuple[str, ...]
    timed_as: str
    reported: bool = True


CACHED_STAGES: dict[str, CachedStage] = {
    "segment": CachedStage((), "segment"),
    # the largest blob read for its look, which decides where it is searched
    "first blob": CachedStage(("segment",), "segment"),
    # the plaque-shaped regions cut at one gray level
    "quads": CachedStage(("segment",), "segment"),
    # A region's features depend on the region alone, not on the segmentation that proposed it.
    "features": CachedStage((), "features"),
    "match": CachedStage(("features",), "match"),
    # a region's features matched with the library's simulated steep views (`library_affine_features`)
    "affine match": CachedStage(("features",), "match"),
    "plaque": CachedStage(("quads",), "match"),
    # Its inputs, the winner's H and correspondences, carry what the stages before it found: a RANSAC or
    # decision change usually leaves them as they were. The pose itself is estimated every time.
    "refine": CachedStage((), "pose", reported=False),
}
# Cached on the `Library` (`library_features`), for every image at once.
LIBRARY_STAGES = ("library features",)
# Run afresh every time: a setting that only these read is in no cache key.
UNCACHED_STAGES = ("regions", "ransac", "decide", "text check", "pose")
ALL_STAGES = (*CACHED_STAGES, *LIBRARY_STAGES, *UNCACHED_STAGES)


def stage_reads(stage: str) -> frozenset[str]:
    """`stage` and every cached stage whose results it reads, directly or through another."""
    reads = CACHED_STAGES[stage].reads if stage in CACHED_STAGES else ()
    return frozenset({stage}).union(*(stage_reads(s) for s in reads))


@functools.cache
def feeding_settings(stage: str) -> tuple[str, ...]:
    """The names of the settings that feed `stage` or a cached stage it reads, in `Settings`' field order."""
    if stage not in CACHED_STAGES and stage not in LIBRARY_STAGES:
        raise KeyError(f"{stage!r} is not a cached stage: {', '.join((*CACHED_STAGES, *LIBRARY_STAGES))}")
    stages = stage_reads(stage)
    return tuple(f.name for f in dataclasses.fields(Settings) if stages.intersection(f.metadata["stages"]))


def stage_key(settings: Settings, stage: str) -> tuple:
    """What the results of cached `stage` depend on besides its inputs: the values of `feeding_settings`."""
    return tuple(getattr(settings, name) for name in feeding_settings(stage))


def nbytes(value: Any) -> int:
    """Bytes held by the numpy arrays in a stage result (a dataclass, list or tuple of them)."""
    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, (list, tuple)):
        return sum(nbytes(v) for v in value)
    if hasattr(value, "__dict__"):
        return sum(nbytes(v) for v in vars(value).values())
    return 0


class StageCache:
    """Results of earlier stages for one image, keyed by the settings each stage depends on.

    Least recently used entries are dropped beyond `max_entries` or `max_bytes` of arrays, so a
    slider sweep over many values cannot grow memory without bound (a segmentation of a 12 MP
    photo alone holds about 100 MB).
    """

    def __init__(self, max_entries: int = 64, max_bytes: int = 64 * 2**20) -> None:
        self.max_entries = max_entries
        self.max_bytes = max_bytes
        self._entries: OrderedDict[Hashable, tuple[Any, int]] = OrderedDict()
        self._bytes = 0

    def get(self, key: Hashable, compute: Callable[[], T]) -> T:
        """The entry under `key`, computing and storing it first when absent."""
        if key in self._entries:
            self._entries.move_to_end(key)
            return self._entries[key][0]
        value = compute()
        size = nbytes(value)
        self._entries[key] = (value, size)
        self._bytes += size
        # The newest entry stays even when it alone exceeds the budget: it is the one in use.
        while len(self._entries) > 1 and (len(self._entries) > self.max_entries or self._bytes > self.max_bytes):
            self._bytes -= self._entries.popitem(last=False)[1][1]
        return value

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._entries

    @property
    def bytes(self) -> int:
        return self._bytes


class StageRunner:
    """Times the stages of one `recognize` run and caches the results of its cached stages.

    timing: milliseconds per entry of STAGES, each counting its own work only (a stage run inside
    another, as the plaque search cuts quads, is taken out of the outer one's time); reused: the
    entries whose results came in whole or part from `cache`, so that their times are a lookup's,
    not what the stage costs. Without `cache` every stage is computed.
    """

    def __init__(self, settings: Settings, cache: StageCache | None) -> None:
        self.settings = settings
        self.cache = cache
        self.timing = dict.fromkeys(STAGES, 0.0)
        self.reused: set[str] = set()
        self._inner_ms: list[float] = []  # per open `timed` block, the time of the blocks inside it

    @contextlib.contextmanager
    def timed(self, entry: str) -> Iterator[None]:
        """Count the time of the block in `timing[entry]` (one of STAGES), less that of blocks inside it."""
        t0 = time.perf_counter()
        self._inner_ms.append(0.0)
        try:
            yield
        finally:
            elapsed = (time.perf_counter() - t0) * 1e3
            self.timing[entry] += elapsed - self._inner_ms.pop()
            if self._inner_ms:
                self._inner_ms[-1] += elapsed

    def run(self, stage: str, compute: Callable[[], T], inputs: tuple = (), *, settings: Settings | None = None) -> T:
        """`compute()`, the result of cached `stage` on `inputs` (what it depends on besides the image
        and the settings of `stage_key`), timed, and taken from the cache when it is there.
        `settings`: those `compute` runs with where they differ from the run's (a picture's view
        searched with a grown feature budget), so that its key holds what it was computed with."""
        spec = CACHED_STAGES[stage]
        with self.timed(spec.timed_as):
            if self.cache is None:
                return compute()
            key = (stage, inputs, stage_key(self.settings if settings is None else settings, stage))
            if spec.reported and key in self.cache:
                self.reused.add(spec.timed_as)
            return self.cache.get(key, compute)

    def reused_stages(self) -> list[str]:
        """The entries of STAGES reused, in STAGES order."""
        return sorted(self.reused, key=STAGES.index)
