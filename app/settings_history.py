"""The state every result depends on, as one frozen `Snapshot`, and the settings of past versions.

A result is tagged with the snapshot's generation and settings version it was computed from; the
settings of the last SETTINGS_HISTORY versions are kept so a client can check a result against
the settings it was computed with.
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from signpose.pipeline.camera import Camera
from signpose.pipeline.exif import ExifCamera
from signpose.pipeline.library import Library
from signpose.pipeline.settings import Settings

# Settings versions whose settings are kept, so a result's version can be checked against them.
SETTINGS_HISTORY = 1000


@dataclass(frozen=True)
class Snapshot:
    """Everything a result depends on. `generation` grows with every change to any of it.

    `camera` None: per image its EXIF focal length, else `assumed_hfov_deg` (horizontal, degrees).
    """

    generation: int
    settings_version: int
    settings: Settings
    library: Library
    camera: Camera | None
    assumed_hfov_deg: float

    def camera_for(self, exif: ExifCamera, width: int, height: int) -> Camera:
        """The intrinsics an image decoded to `width` x `height` px is recognised with: the workspace's
        camera turned as its EXIF orientation turned it, else the image's EXIF focal length, else the
        assumed field of view (`ExifCamera.camera_for`). CameraError when the camera does not fit it."""
        return exif.camera_for(self.camera, width, height, self.assumed_hfov_deg)


class SettingsHistory:
    """The current `Snapshot` and the settings of the versions before it.

    `_lock` guards `_snap` and `_history` together: a change reads the current snapshot, makes the
    next and records its settings as one step, so concurrent partial changes all land and a version
    is never listed without its settings. `current` is read without it (a reference swap is atomic).
    """

    def __init__(self, first: Snapshot) -> None:
        self._lock = threading.Lock()
        self._snap = first
        self._history: dict[int, Settings] = {first.settings_version: first.settings}  # oldest first

    @property
    def current(self) -> Snapshot:
        return self._snap

    def change(self, make: Callable[[Snapshot], dict[str, Any]]) -> Snapshot | None:
        """Swap in the next snapshot with the fields `make(current)` returns (none: no change, None
        returned). A new `settings` is a new settings version. `make` runs under the lock: it must not
        call back into the history."""
        with self._lock:
            snap = self._snap
            changes = make(snap)
            if not changes:
                return None
            bump = "settings" in changes
            self._snap = dataclasses.replace(snap, generation=snap.generation + 1,
                                             settings_version=snap.settings_version + bump, **changes)
            if bump:
                self._history[self._snap.settings_version] = self._snap.settings
                if len(self._history) > SETTINGS_HISTORY:
                    del self._history[next(iter(self._history))]
            return self._snap

    def settings_at(self, version: int) -> Settings:
        """The settings of `version` (one of `versions()`); KeyError when not kept."""
        with self._lock:
            return self._history[version]

    def versions(self) -> range:
        """The settings versions whose settings are kept: the last SETTINGS_HISTORY."""
        with self._lock:
            return range(next(iter(self._history)), self._snap.settings_version + 1)
