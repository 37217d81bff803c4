"""Flights in the viser 3D view: each flight's camera trajectory in the world of every sign it saw.

In a sign's world (app/scene.py: the sign frame, metres) a flight is drawn under
``/signs/<label>/flights/<flight id>/``: `trajectory`, line segments through the camera's
positions on consecutive frames that saw the sign (the filtered pose where there is one, else the
measured one; a frame without the sign breaks the line), `frusta/<frame>`, a small frustum every
`FRUSTUM_EVERY_S` seconds of video, and `current`, the frustum of the frame the page shows
(`Flight.cursor`), with that frame on it, hidden in the worlds of signs the frame does not see.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
import viser

from signpose.pipeline.library import Library

from .flights import Flight, Flights
from .scene import THUMBNAIL_WIDTH_PX, camera_pose_in_sign, fit_width, frustum_scale, frustum_shape, label_rgb

FRUSTUM_EVERY_S = 1.0
DEFAULT_FPS = 30.0
CURRENT_RGB = (230, 120, 0)
# The frusta along the way, smaller than the current one, so the current one stands out.
TRAIL_SCALE = 0.5


@dataclass(frozen=True)
class Seen:
    """One frame's camera in one sign's frame: its `frame` index, `position` (3,) m and `wxyz` orientation."""

    frame: int
    position: np.ndarray
    wxyz: np.ndarray


def sightings(records: list[dict]) -> dict[str, list[Seen]]:
    """By sign label, the camera of every frame that saw the sign with a pose, in frame order (the
    filtered pose where there is one; the first track of a label on a frame)."""
    seen: dict[str, list[Seen]] = {}
    for record in records:
        labels_done: set[str] = set()
        for sign in record["signs"]:
            pose = sign["filtered_pose"] or sign["pose"]
            if pose is None or sign["label"] in labels_done or pose["R"] is None or pose["t"] is None:
                continue
            labels_done.add(sign["label"])
            position, wxyz = camera_pose_in_sign(np.array(pose["R"], float), np.array(pose["t"], float))
            seen.setdefault(sign["label"], []).append(Seen(int(record["frame"]), position, wxyz))
    return seen


def trajectory_segments(seen: list[Seen]) -> np.ndarray:
    """(N, 2, 3) m: segments joining the positions of consecutive frames (a gap breaks the line)."""
    pairs = [(a.position, b.position) for a, b in zip(seen, seen[1:]) if b.frame == a.frame + 1]
    return np.array(pairs, dtype=np.float32).reshape(-1, 2, 3)


@dataclass
class FlightNodes:
    """What one flight shows in one sign's world, and what it was drawn from."""

    result_version: int
    trajectory: viser.LineSegmentsHandle
    frusta: list[viser.CameraFrustumHandle]
    current: viser.CameraFrustumHandle
    by_frame: dict[int, Seen] = field(repr=False)
    cursor: int = -1

    def remove(self) -> None:
        self.current.remove()
        for frustum in self.frusta:
            frustum.remove()
        self.trajectory.remove()


class FlightLayer:
    """The flights drawn in a viser scene, by (flight id, sign label); the scene's redraw thread calls
    `draw`, under the scene's lock."""

    def __init__(self, server: viser.ViserServer, flights: Flights) -> None:
        self.server, self.flights = server, flights
        self.nodes: dict[tuple[str, str], FlightNodes] = {}
        # By flight id: the result_version and the `sightings` of that run, worked out once a run.
        self._seen: dict[str, tuple[int, dict[str, list[Seen]]]] = {}

    def seen(self, flight: Flight) -> dict[str, list[Seen]]:
        """`sightings` of the flight's last complete run."""
        cached = self._seen.get(flight.id)
        if cached is None or cached[0] != flight.result_version:
            cached = self._seen[flight.id] = (flight.result_version, sightings(flight.records))
        return cached[1]

    def labels(self) -> set[str]:
        """The signs some flight's trajectory is drawn for (their worlds must exist)."""
        return {label for flight in self.flights.held() for label in self.seen(flight)}

    def points(self, label: str) -> list[np.ndarray]:
        """(N, 3) m each: the camera positions drawn in sign `label`'s world, to frame views on."""
        return [np.array([f.position for f in nodes.frusta], float).reshape(-1, 3)
                for (_, drawn), nodes in self.nodes.items() if drawn == label]

    def clear(self) -> None:
        for nodes in self.nodes.values():
            nodes.remove()
        self.nodes.clear()

    def prune(self, library: Library) -> None:
        """Take away the nodes of flights no longer held and of signs they no longer see: before the
        scene removes a sign's world, which takes its nodes with it."""
        held = {flight.id: flight for flight in self.flights.held()}
        self._seen = {k: v for k, v in self._seen.items() if k in held}
        wanted = {(flight.id, label) for flight in held.values() for label in self.seen(flight)
                  if label in library.ids}
        for key in set(self.nodes) - wanted:
            self.nodes.pop(key).remove()

    def draw(self, library: Library, photo_width_m: float, *, redraw_all: bool = False) -> None:
        """Draw the flights held (`prune` has taken the others away): new runs drawn, each current
        frustum at its flight's cursor."""
        for flight in self.flights.held():
            for label, seen in self.seen(flight).items():
                if label not in library.ids:
                    continue
                key = (flight.id, label)
                nodes = self.nodes.get(key)
                if nodes is None or nodes.result_version != flight.result_version or redraw_all:
                    if nodes is not None:
                        nodes.remove()
                    nodes = self.nodes[key] = self._add(flight, label, seen, library, photo_width_m)
                self._show_cursor(flight, nodes)

    def cursor_labels(self, flight_id: str) -> list[str]:
        """The signs whose world shows the flight's current frame."""
        return [label for (fid, label), nodes in self.nodes.items()
                if fid == flight_id and nodes.current.visible]

    def show_cursor(self, flight_id: str) -> None:
        """Move the flight's current frustums to its cursor."""
        try:
            flight = self.flights.get(flight_id)
        except KeyError:
            return
        for (fid, _), nodes in self.nodes.items():
            if fid == flight_id:
                self._show_cursor(flight, nodes)

    def _show_cursor(self, flight: Flight, nodes: FlightNodes) -> None:
        show_current(self.server, flight, nodes)

    def _add(self, flight: Flight, label: str, seen: list[Seen], library: Library, photo_width_m: float) -> FlightNodes:
        return add_flight_nodes(self.server, f"/signs/{label}/flights/{flight.id}", flight, seen,
                                label_rgb(library, label), photo_width_m)


def add_flight_nodes(server: viser.ViserServer, root: str, flight: Flight, seen: list[Seen],
                     color: tuple[int, int, int], photo_width_m: float) -> FlightNodes:
    """The flight's cameras `seen` drawn under `root`: its trajectory and a frustum every FRUSTUM_EVERY_S
    in `color`, and the current camera (hidden until `show_current` places it)."""
    scene = server.scene
    trajectory = scene.add_line_segments(f"{root}/trajectory", trajectory_segments(seen), color,
                                         thickness=3.0, thickness_units="screen")
    fov, aspect = frustum_of(flight)
    scale = frustum_scale(fov, aspect, photo_width_m)
    every = max(1, round(FRUSTUM_EVERY_S * (flight.fps or DEFAULT_FPS)))
    frusta = [scene.add_camera_frustum(f"{root}/frusta/{s.frame}", fov, aspect, scale=TRAIL_SCALE * scale,
                                       color=color, thickness=1.0, thickness_units="screen",
                                       position=s.position, wxyz=s.wxyz)
              for s in seen if s.frame % every == 0]
    current = scene.add_camera_frustum(f"{root}/current", fov, aspect, scale=scale, color=CURRENT_RGB,
                                       thickness=3.0, thickness_units="screen", visible=False)
    return FlightNodes(flight.result_version, trajectory, frusta, current, {s.frame: s for s in seen})


def show_current(server: viser.ViserServer, flight: Flight, nodes: FlightNodes) -> None:
    """Move `nodes`' current camera to the flight's cursor, with that frame on it; hidden on a frame it did
    not see."""
    cursor = flight.cursor
    if nodes.cursor == cursor:
        return
    nodes.cursor = cursor
    seen = nodes.by_frame.get(cursor)
    if seen is None:
        nodes.current.visible = False
        return
    with server.atomic():
        nodes.current.position, nodes.current.wxyz = seen.position, seen.wxyz
        image = frame_thumbnail(flight, cursor)
        if image is not None:
            nodes.current.image = image
        nodes.current.visible = True


def frame_thumbnail(flight: Flight, index: int) -> np.ndarray | None:
    """Frame `index` of the flight as an RGB thumbnail for a frustum (THUMBNAIL_WIDTH_PX wide at most);
    None when its JPEG is not kept."""
    if not 0 <= index < len(flight.jpegs):
        return None
    return fit_width(cv2.imdecode(np.frombuffer(flight.jpegs[index], np.uint8), cv2.IMREAD_COLOR), THUMBNAIL_WIDTH_PX)


def frustum_of(flight: Flight) -> tuple[float, float]:
    """(vertical fov in radians, aspect) of the flight's camera, as `frustum_shape` gives them."""
    camera = flight.intrinsics or {"fx": flight.width, "fy": flight.width}
    K = np.array([[camera["fx"], 0, flight.width / 2], [0, camera["fy"], flight.height / 2], [0, 0, 1]])
    return frustum_shape(flight.width, flight.height, K)
