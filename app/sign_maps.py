"""The sign map `signpose serve` holds (docs/map.md): loaded from a map file (`--map`, the page) or
built from the photos and flights held, as `signpose map build` builds one from files
(pipeline/map_build.py); drawn in the 3D scene's map world and downloaded as YAML. Kept in the
state directory (`map.yaml`, the map file as downloaded) and held again at the next start, unless
`--map` gives another (`open_sign_maps`).

A build's observations: every library sign in each photo held (`Workspace.signs_in_view`), keyed by
the image's id, and from each flight's last complete run the measured poses of the signs on the
frames `takes_frame` takes, keyed `<flight id>#<frame>`, as `map build` takes a flight's frames.
The cameras in the map frame (the scene's) are located by `pipeline.localise.locate_in_map` from
every sign each photo (`Workspace.signs_in_view`, as a build searches it) or frame sees.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from signpose.pipeline.camera import Camera
from signpose.pipeline.every_sign import SignSeen
from signpose.pipeline.library import Library
from signpose.pipeline.localise import CameraInMap, locate_in_map
from signpose.pipeline.map_build import (MapBuild, MapBuildError, Observation, SignReport, build_map, observations_of,
                                         takes_frame)
from signpose.pipeline.pose import Pose
from signpose.pipeline.sign_map import SignMap, load_sign_map, sign_map_yaml

from .flights import Flight, Flights
from .state import KeptMap, StateDir, StateError
from .workspace import Workspace, say_kept

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BuildReport:
    """What a map build here found beyond the map: how the survey saw each sign (`signs`), the
    observations rejected as inconsistent, as (image name, sign id, chi2), the signs no map could hold
    (`unmapped`: id -> why) and the photos that could not be run (`warnings`). Kept in the state
    directory beside the map, so a restart does not lose it."""

    signs: dict[str, SignReport]
    rejected: tuple[tuple[str, str, float], ...] = ()
    unmapped: dict[str, str] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()

    @staticmethod
    def of(build: MapBuild, names: dict[str, str], warnings: list[str]) -> BuildReport:
        """The report of `build`, its observations' image keys named by `names`."""
        return BuildReport(dict(build.reports), tuple(
            (names.get(r.observation.image, r.observation.image), r.observation.sign_id, r.chi2) for r in build.rejected),
            dict(build.unmapped), tuple(warnings))

    def to_json(self) -> dict:
        return {"signs": {i: dataclasses.asdict(r) for i, r in self.signs.items()},
                "rejected": [list(r) for r in self.rejected], "unmapped": self.unmapped, "warnings": list(self.warnings)}

    @staticmethod
    def from_json(data: dict) -> BuildReport:
        """The report `to_json` gave; KeyError, TypeError or ValueError for anything else."""
        return BuildReport({str(i): SignReport(**r) for i, r in data["signs"].items()},
                           tuple((str(image), str(sign), float(chi2)) for image, sign, chi2 in data["rejected"]),
                           {str(i): str(why) for i, why in data["unmapped"].items()},
                           tuple(str(w) for w in data["warnings"]))


@dataclass(frozen=True, eq=False)
class HeldMap:
    """The map held: `sign_map`; `source`, where it came from (a file's name, or what it was built
    from); `revision`, +1 on every change of the map held; for a map built here, its `report`."""

    sign_map: SignMap
    source: str
    revision: int
    report: BuildReport | None = None

    def yaml(self) -> str:
        """The map file's text; a built map's signs carry the build's report as comments."""
        return sign_map_yaml(self.sign_map, None if self.report is None else
                             {sign_id: r.lines() for sign_id, r in self.report.signs.items()})


class SignMaps:
    """The one map a server holds, or none. Thread-safe; `publish("map", {"revision"})` on every change,
    which is kept in `state` when given (its map file, or none)."""

    def __init__(self, *, publish: Callable[[str, dict], None], state: StateDir | None = None) -> None:
        self._publish = publish
        self._state = state
        self._lock = threading.Lock()
        self._held: HeldMap | None = None
        self._revision = 0

    @property
    def held(self) -> HeldMap | None:
        return self._held

    def hold_file(self, sign_map: SignMap, name: str, *, kept: bool = False) -> HeldMap:
        """Hold `sign_map`, read from the map file `name`; `kept`: it is the state's map already."""
        return self._hold(lambda revision: HeldMap(sign_map, name, revision), keep=not kept)

    def hold_build(self, build: MapBuild, source: str, names: dict[str, str], warnings: list[str]) -> HeldMap:
        """Hold the map of `build`, made from `source` (said for people), its observations' image keys
        named by `names`."""
        report = BuildReport.of(build, names, warnings)
        return self._hold(lambda revision: HeldMap(build.sign_map, source, revision, report))

    def hold_kept(self, sign_map: SignMap, origin: KeptMap | None, name: str) -> HeldMap:
        """Hold `sign_map`, the state's map file `name`, with what the state kept of its `origin`
        (where it came from, its build's report; None: nothing)."""
        source, report = f"{name} kept from the last run", None
        if origin is not None:
            source = f"{origin.source}, kept from the last run"
            try:
                report = None if origin.report is None else BuildReport.from_json(origin.report)
            except (KeyError, TypeError, ValueError) as exc:
                log.warning("the sign map's build report kept in the state cannot be read (%s): it is left out", exc)
        return self._hold(lambda revision: HeldMap(sign_map, source, revision, report), keep=False)

    def clear(self) -> None:
        with self._lock:
            if self._state is not None:
                self._state.save_map(None)
            self._held = None
            self._revision += 1
            revision = self._revision
        self._publish("map", {"revision": revision})

    def _hold(self, make: Callable[[int], HeldMap], keep: bool = True) -> HeldMap:
        with self._lock:
            held = make(self._revision + 1)   # raises before anything changes
            if keep and self._state is not None:
                self._state.save_map(held.yaml(), KeptMap(held.source, None if held.report is None else
                                                          held.report.to_json()))
            self._held, self._revision = held, held.revision
        self._publish("map", {"revision": held.revision})
        return held


def open_sign_maps(workspace: Workspace) -> SignMaps:
    """The map a server on `workspace` starts with, kept in its state directory: `--map`'s
    (config.map_file; a different map the state kept is moved aside and logged, as `--camera` does;
    MapError for a file that cannot be used), else the one the state kept. A kept map that no longer
    fits the library (a sign removed, the library replaced) is moved aside, logged, and the server
    starts without one."""
    state, ids, file = workspace.state, workspace.library.ids, workspace.config.map_file
    maps = SignMaps(publish=workspace.publish, state=state)
    if file is not None:
        sign_map = load_sign_map(file, ids)
        say_kept("map", file, state.replace_map(sign_map_yaml(sign_map)))
        maps.hold_file(sign_map, file.name, kept=True)
        return maps
    try:
        sign_map = state.load_map(ids)
    except StateError as exc:
        log.warning("%s: it is kept in %s", exc, state.set_map_aside())
        return maps
    if sign_map is not None:
        maps.hold_kept(sign_map, state.load_map_origin(), state.map_path.name)
    return maps


def recorded_signs(record: dict) -> list[SignSeen]:
    """The signs of one flight record (a frame, as `signpose track --json` keeps it), with their measured
    poses (None where there is none)."""
    signs = []
    for sign in record["signs"]:
        measured, pose = sign["pose"], None
        if measured is not None and measured["R"] is not None and measured["t"] is not None:
            covariance = measured["covariance"]   # non-finite numbers are null in JSON: NaN here
            pose = Pose(R=np.array(measured["R"], float), t=np.array(measured["t"], float), method="recorded",
                        reprojection_rmse_px=measured["reprojection_rmse_px"] or float("nan"),
                        ambiguous=measured["ambiguous"], solution_errors=None,
                        covariance=None if covariance is None else np.array(covariance, dtype=float))
        signs.append(SignSeen(sign["label"], np.array(sign["corners"], float), pose))
    return signs


def frame_key(flight: Flight, index: int) -> str:
    """The image key of frame `index` of `flight` among a build's observations."""
    return f"{flight.id}#{index}"


def survey(workspace: Workspace, flights: Flights, stop: threading.Event | None = None,
           ) -> tuple[list[Observation], dict[str, str], str, list[str]]:
    """Every observation the photos and flights held give a map: (observations, image key -> name,
    what they came from, warnings for the photos that could not be run). TimeoutError when `stop` is set."""
    records = workspace.images()
    names = {r.id: r.name for r in records}
    observations: list[Observation] = []
    warnings = []
    for record, found in zip(records, workspace.signs_in_view(records, stop)):
        if found is None:
            warnings.append(f"{record.name} could not be run (its result says why) and is left out")
        else:
            observations += observations_of(record.id, found)
    done = [f for f in flights.held() if f.records]
    for flight in done:
        for record in flight.records:
            index = int(record["frame"])
            if takes_frame(index, len(record["signs"])):
                names[frame_key(flight, index)] = f"{flight.name} frame {index}"
                observations += observations_of(frame_key(flight, index), recorded_signs(record))
    source = f"built from {len(records)} photo(s) and {len(done)} flight(s)"
    return observations, names, source, warnings


def build_from_held(workspace: Workspace, flights: Flights, anchor: str | None,
                    stop: threading.Event | None = None) -> tuple[MapBuild, str, dict[str, str], list[str]]:
    """The map of the photos and flights held, in the frame of `anchor` (default: the first sign seen)
    (`build_map`), with what it came from, the image names and the warnings of `survey`. MapBuildError
    when no map can be built (no sign seen, the anchor not seen, signs in groups no image links)."""
    observations, names, source, warnings = survey(workspace, flights, stop)
    if not observations:
        raise MapBuildError(f"no sign with a pose in the photos and flights held ({source.removeprefix('built from ')}): "
                            "add survey photos in which neighbouring signs are seen together")
    return build_map(observations, anchor=anchor), source, names, warnings


def in_view_json(found: list[SignSeen], held: HeldMap | None, library: Library, camera: Camera | None) -> dict:
    """A result's `signs` (every sign `found` in the image, each {label, corners, pose}) and, with a map `held`, its
    `camera_in_map` (null where no mapped sign is in view), as `signpose recognize --json [--map]` gives them."""
    located = camera_in_map(found, held.sign_map, library, camera) if held is not None else None
    return {"signs": [sign.to_json() for sign in found if sign.label is not None],
            "camera_in_map": None if located is None else located.to_json()}


def camera_in_map(found: list[SignSeen], sign_map: SignMap, library: Library, camera: Camera | None) -> CameraInMap | None:
    """The camera of a photo or frame in the map frame, from the signs `found` in it (`locate_in_map`);
    None without a camera or a mapped sign among them."""
    if camera is None:
        return None
    return locate_in_map(found=found, sign_map=sign_map, library=library, camera=camera)
