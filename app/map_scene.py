"""The sign map in the viser 3D view: the "map" world beside the per-sign worlds (app/scene.py).

Under ``/map`` (the map frame, metres: X_map = R·X_sign + position_m, docs/map.md) every mapped
library sign is drawn in place as the sign worlds draw a sign (``signs/<id>``), with the 3-sigma
ellipsoid of its position (``uncertainty/<id>``: axes along the eigenvectors of its position
covariance, half-lengths three times their sigma) and a label giving its worst-direction 1-sigma.
Each photo that sees a mapped sign is drawn as a frustum (``cameras/<image id>``), and each
flight as its camera's trajectory through the frames located in the map (``flights/<id>/``, as
app/flight_scene.py draws one in a sign's world: ``trajectory``, ``frusta/<frame>`` and ``current``,
the frame the page shows), the cameras located from every sign they see (a photo's as
`Workspace.signs_in_view` finds them) by `pipeline.localise.locate_in_map` (app/sign_maps.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import viser
import viser.transforms as tf

from signpose.pipeline.every_sign import SignSeen
from signpose.pipeline.library import Library
from signpose.pipeline.localise import CameraInMap
from signpose.pipeline.recognize import Recognition
from signpose.pipeline.sign_map import MappedSign

from .flight_scene import FlightNodes, Seen, add_flight_nodes, show_current
from .flights import Flight, Flights
from .image_store import ImageRecord
from .scene import SignNodes, add_sign_nodes, frustum_scale, frustum_shape, label_rgb
from .sign_maps import HeldMap, SignMaps, camera_in_map, recorded_signs

ROOT = "/map"
# How many sigma the drawn ellipsoid of a sign's position reaches.
ELLIPSOID_SIGMAS = 3.0
ELLIPSOID_RGB = (220, 40, 160)
ELLIPSOID_OPACITY = 0.35
# A flight's trajectory in the map world, which no one sign's colour stands for.
FLIGHT_RGB = (23, 190, 207)


def ellipsoid_axes(covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(wxyz (4,), half-lengths (3,) m) of the ELLIPSOID_SIGMAS ellipsoid of a (3, 3) position
    covariance (m²): a rotation whose columns are its eigenvectors, and ELLIPSOID_SIGMAS times their sigma."""
    variances, axes = np.linalg.eigh(0.5 * (covariance + covariance.T))
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return tf.SO3.from_matrix(axes).wxyz, ELLIPSOID_SIGMAS * np.sqrt(np.maximum(variances, 0.0))


def sign_text(sign: MappedSign) -> str:
    """A mapped sign's label: its id and worst-direction 1-sigma."""
    sigma = sign.worst_sigma()
    if sigma is None:
        return sign.sign_id
    return f"{sign.sign_id} ±{1e3 * sigma[0]:.1f} mm {math.degrees(sigma[1]):.2f}°"


@dataclass
class MappedSignNodes:
    """One mapped sign in the map world: the sign as a sign world draws it, its label and its ellipsoid
    (None without a covariance)."""

    sign: SignNodes
    label: viser.LabelHandle
    ellipsoid: viser.IcosphereHandle | None

    def remove(self) -> None:
        if self.ellipsoid is not None:
            self.ellipsoid.remove()
        self.label.remove()
        self.sign.remove()


InView = Callable[[list[ImageRecord]], list[list[SignSeen] | None]]


class MapLayer:
    """The map world of a viser scene; the scene's redraw thread calls `draw`, under the scene's lock.
    What it drew is of map revision `revision` (-1: no map). `signs_in_view`: every sign in each of
    some photos (`Workspace.signs_in_view`; None for a photo that could not be run)."""

    def __init__(self, server: viser.ViserServer, sign_maps: SignMaps, flights: Flights | None,
                 signs_in_view: InView) -> None:
        self.server, self.sign_maps, self.flights = server, sign_maps, flights
        self.signs_in_view = signs_in_view
        self.root = server.scene.add_frame(ROOT, show_axes=False, visible=False)
        self.revision = -1
        self.signs: dict[str, MappedSignNodes] = {}
        # By image id: the recognition drawn, its camera in the map (None: not located) and its frustum.
        self.cameras: dict[str, tuple[Recognition, CameraInMap | None, viser.CameraFrustumHandle | None]] = {}
        self.flight_nodes: dict[str, FlightNodes] = {}

    @property
    def held(self) -> HeldMap | None:
        return self.sign_maps.held

    def clear(self) -> None:
        """Take away everything drawn (the library changed, or the map): `draw` draws it again."""
        for nodes in self.signs.values():
            nodes.remove()
        for _, _, frustum in self.cameras.values():
            if frustum is not None:
                frustum.remove()
        for flight in self.flight_nodes.values():
            flight.remove()
        self.signs, self.cameras, self.flight_nodes = {}, {}, {}
        self.revision = -1

    def points(self) -> list[np.ndarray]:
        """(N, 3) m each, in the map frame: the signs' outlines and the cameras drawn, to frame views on."""
        held = self.held
        if held is None:
            return []
        points = [np.asarray(n.sign.outline.points, float).reshape(-1, 3) @ tf.SO3(n.sign.frame.wxyz).as_matrix().T
                  + np.asarray(n.sign.frame.position) for n in self.signs.values()]
        points += [np.asarray(camera.position_m).reshape(1, 3) for _, camera, _ in self.cameras.values()
                   if camera is not None]
        points += [np.array([f.position for f in nodes.frusta], float).reshape(-1, 3)
                   for nodes in self.flight_nodes.values()]
        return points

    def draw(self, library: Library, shown: list[tuple[ImageRecord, Recognition]], photo_width_m: float, *,
             redraw_all: bool = False) -> None:
        """Bring the map world in line with the map held, the photos `shown` (those with a pose) and
        the flights' last runs."""
        held = self.held
        if held is None or held.revision != self.revision or redraw_all:
            self.clear()
        if held is None:
            return
        if self.revision != held.revision:
            self.revision = held.revision
            for sign in held.sign_map.signs.values():
                if sign.sign_id in library.ids:
                    self.signs[sign.sign_id] = self._add_sign(sign, library)
        self._draw_cameras(held, library, shown, photo_width_m)
        self._draw_flights(held, library, photo_width_m)

    def _add_sign(self, sign: MappedSign, library: Library) -> MappedSignNodes:
        scene = self.server.scene
        wxyz = tf.SO3.from_matrix(sign.R).wxyz
        nodes = add_sign_nodes(self.server, f"{ROOT}/signs/{sign.sign_id}", library[sign.sign_id], wxyz=wxyz,
                               position=sign.position_m)
        label = scene.add_label(f"{ROOT}/signs/{sign.sign_id}/label", sign_text(sign))
        ellipsoid = None
        if sign.covariance is not None:
            axes_wxyz, half_lengths = ellipsoid_axes(sign.covariance[:3, :3])
            x, y, z = np.maximum(half_lengths, 1e-9)   # a zero scale would leave viser no shape to draw
            ellipsoid = scene.add_icosphere(f"{ROOT}/uncertainty/{sign.sign_id}", radius=1.0, color=ELLIPSOID_RGB,
                                            scale=(float(x), float(y), float(z)),
                                            opacity=ELLIPSOID_OPACITY, wxyz=axes_wxyz, position=sign.position_m)
        return MappedSignNodes(nodes, label, ellipsoid)

    def _draw_cameras(self, held: HeldMap, library: Library, shown: list[tuple[ImageRecord, Recognition]],
                      photo_width_m: float) -> None:
        wanted = {record.id: rec for record, rec in shown}
        for image_id in set(self.cameras) - set(wanted):
            frustum = self.cameras.pop(image_id)[2]
            if frustum is not None:
                frustum.remove()
        stale = [(record, rec) for record, rec in shown
                 if (drawn := self.cameras.get(record.id)) is None or drawn[0] is not rec]
        in_view = self.signs_in_view([record for record, _ in stale]) if stale else []
        for (record, rec), found in zip(stale, in_view):
            image_id, drawn = record.id, self.cameras.get(record.id)
            if drawn is not None and drawn[2] is not None:
                drawn[2].remove()
            camera = camera_in_map(found or [SignSeen.of(rec)], held.sign_map, library, rec.camera)
            frustum = None
            if camera is not None:
                fov, aspect = frustum_shape(*rec.image_size, rec.camera.K)
                frustum = self.server.scene.add_camera_frustum(
                    f"{ROOT}/cameras/{image_id}", fov, aspect, scale=frustum_scale(fov, aspect, photo_width_m),
                    color=label_rgb(library, camera.signs_used[0]), thickness=2.0, thickness_units="screen",
                    position=camera.position_m, wxyz=tf.SO3.from_matrix(camera.R).wxyz)
            self.cameras[image_id] = (rec, camera, frustum)

    def _draw_flights(self, held: HeldMap, library: Library, photo_width_m: float) -> None:
        flights = {f.id: f for f in self.flights.held()} if self.flights is not None else {}
        for flight_id in set(self.flight_nodes) - set(flights):
            self.flight_nodes.pop(flight_id).remove()
        for flight in flights.values():
            drawn = self.flight_nodes.get(flight.id)
            if drawn is None or drawn.result_version != flight.result_version:
                if drawn is not None:
                    drawn.remove()
                drawn = self.flight_nodes[flight.id] = self._add_flight(flight, held, library, photo_width_m)
            show_current(self.server, flight, drawn)

    def show_cursor(self, flight_id: str) -> None:
        """Move the flight's current camera to its cursor (hidden on a frame not located in the map)."""
        nodes = self.flight_nodes.get(flight_id)
        flight = next((f for f in self.flights.held() if f.id == flight_id), None) if self.flights is not None else None
        if nodes is not None and flight is not None:
            show_current(self.server, flight, nodes)

    def _add_flight(self, flight: Flight, held: HeldMap, library: Library, photo_width_m: float) -> FlightNodes:
        seen = [Seen(int(record["frame"]), camera.position_m, tf.SO3.from_matrix(camera.R).wxyz)
                for record in flight.records
                if (camera := camera_in_map(recorded_signs(record), held.sign_map, library,
                                            flight.tracked_camera)) is not None]
        return add_flight_nodes(self.server, f"{ROOT}/flights/{flight.id}", flight, seen, FLIGHT_RGB, photo_width_m)
