"""The viser 3D view of a Workspace: signs, estimated cameras, inlier matches and tuning sliders.

Frames: every sign defines its own world (the sign frame: origin at the sign centre, x right,
y down the sign, z into the wall, metres). A pose (R, t) maps X_cam = R·X_sign + t with an
OpenCV camera (x right, y down, z forward); the camera sits at -Rᵀt in the sign frame and its
orientation there is Rᵀ. viser's frustums, image planes and client cameras use the same OpenCV
axes, so Rᵀ goes to viser unchanged (as a wxyz quaternion).

Different signs cannot share one world (they all sit at the origin), so the scene keeps one
subtree per recognised sign under ``/signs/<sign id>`` and a "Sign world" dropdown shows one of
them at a time; the default is the sign with the most recognised images. A sign map held
(app/sign_maps.py) adds one more world, MAP_WORLD, every mapped sign in place (app/map_scene.py),
shown as soon as a map comes to be held.

Workspace events arrive on worker threads; they only mark the scene dirty, and one redraw thread
brings the viser scene up to date at most every `REDRAW_INTERVAL_S`. A viewer's view moving marks
only its labels' layout stale, which that thread lays out again without redrawing the rest.
"""

from __future__ import annotations

import functools
import logging
import math
import statistics
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Literal

import cv2
import numpy as np
import viser
import viser.transforms as tf

from signpose.app.events import Event
from signpose.app.image_store import ImageRecord, Outcome, is_correct, status_of
from signpose.app.viser_compat import SHEET_BELOW_PX, fold_sheet, guard_uploads, run_script
from signpose.app.workspace import Workspace
from signpose.pipeline.library import Library, LibrarySign
from signpose.pipeline.pose import camera_position
from signpose.pipeline.recognize import Recognition
from signpose.pipeline.settings import Settings, SettingsError, settings_schema

if TYPE_CHECKING:
    from signpose.app.flight_scene import FlightLayer
    from signpose.app.flights import Flights
    from signpose.app.map_scene import MapLayer
    from signpose.app.sign_maps import SignMaps

log = logging.getLogger(__name__)

REDRAW_INTERVAL_S = 0.1
THUMBNAIL_WIDTH_PX = 160
# The sign texture only needs to look sharp at a few metres; larger library images waste bandwidth.
SIGN_TEXTURE_MAX_WIDTH_PX = 1024
# Above this many slider positions a slider cannot hit a chosen value; use a number box.
MAX_SLIDER_POSITIONS = 10_000
DEFAULT_FRUSTUM_WIDTH_M = 0.25
# A viewer's camera as it reports it back differs from what was set by float rounding; a person's
# smallest drag moves it by centimetres.
FRAMED_TOLERANCE_M = 1e-3
AMBIGUOUS_RGB = (230, 30, 30)
# tab10 without its red, which marks ambiguous poses.
LABEL_RGB = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (148, 103, 189),
             (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207))
NO_WORLD = "(no sign recognised)"
# The world of the sign map held (app/map_scene.py): every mapped sign in place. Not a sign id (those
# have no parentheses or spaces).
MAP_WORLD = "(sign map)"
# `status_of`'s statuses as the page's top bar words them ("correct" shows as correct/labelled).
STATUS_WORDS = {"wrong": "wrong", "recognized": "recognised (unlabelled)", "none": "no sign (unlabelled)",
                "pending": "pending", "error": "error"}
OUTLINE_RGB = (60, 60, 60)
# Cameras usually stand in front of the sign (z < 0): start to its left and above, looking past it.
INITIAL_VIEW_POSITION_M = (-1.8, -1.0, -2.2)
INITIAL_VIEW_LOOK_AT_M = (0.0, 0.0, -0.8)
# Once there are cameras, new viewers and Reset View see the shown sign and its cameras from that
# side, with room to spare for viser's control panel, which covers part of the frame.
OVERVIEW_MARGIN = 1.4
# viser writes a camera's label rightward and down from it at a size fixed on screen, in CSS px
# whatever the screen's device pixels: 12 px type (the system UI font, else Arial or Helvetica, else
# the sans-serif there is), lines 14 px apart, on a background a fifth of a line larger (viser's
# client/src/label; measured in Chromium: 151 × 28 px for two lines, 302 × 59 device px at 2 to the
# CSS px). Px a character, at most, over those fonts: the widest, DejaVu Sans (Debian's sans-serif,
# measured in Chromium at 12 px: m 11.7, W 11.9, @ 12.0, % 11.4, capitals up to 9.5, w 9.8, digits
# and lower case up to 7.6, . , : ; | ' i j l I J and space up to 4.0; a character outside ASCII, a
# name in Arabic, counted as the widest); a label estimated with Arial's widths, 6.7 px a digit,
# came out 27 px wider than laid out and ran past the view's edge.
LABEL_LINE_PX = 14.0
LABEL_WIDEST_PX, LABEL_WIDE_PX, LABEL_NARROW_PX, LABEL_CHAR_PX = 12.0, 9.9, 4.1, 7.7
LABEL_WIDEST = set("mMW%@")
LABEL_NARROW = set(".,:;|'ijlIJ ")
# Labels nearer each other on screen than this read as one.
LABEL_GAP_PX = 2.0
# Labels are kept this far inside a view's edges: the browser projects the cameras with its own
# rounding of the canvas' size (device px, two or more to the CSS px on a sharp screen), and a label
# laid out here to touch the left edge was drawn 1 px past it there.
LABEL_EDGE_PX = 3.0
# Between the texts a shared label lists on one line.
LABEL_SEPARATOR = "   "
# A shared label lists at most this many texts; one for more says how many and the first and last:
# 43 names, a list as tall as the view, covered the cameras they named.
MAX_TEXTS_LISTED = 6
# A viewer's canvas narrower or lower than this, in CSS px, starts with viser's control panel
# folded: the panel, 320 px wide and as tall as its open folders, covers a third of a view of that
# width or most of one of that height. So it is in the page (its 3D column is at most 28 % of the
# screen wide, its strip under the images 360 px high); a larger view, the pop-out tab on a laptop's
# screen and up, shows it as viser does.
FOLD_PANEL_BELOW_PX = (960.0, 480.0)
# How long a clicked camera's name shows in the clicking viewer.
CLICKED_NOTE_S = 6.0


# --------------------------------------------------------------------------- geometry

def camera_pose_in_sign(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera position (3,) in metres and orientation (4,) wxyz, both in the sign frame, from X_cam = R·X + t."""
    return camera_position(R, t), tf.SO3.from_matrix(np.asarray(R, dtype=np.float64).T).wxyz


def overview_camera(points: np.ndarray, fov_rad: float, aspect: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(position, look_at), each (3,) m in the sign frame, of a view from the side of
    INITIAL_VIEW_POSITION_M that holds all of `points` (N, 3) m, with OVERVIEW_MARGIN to spare,
    in a canvas of vertical field of view `fov_rad` and width / height `aspect` (narrower than
    tall, its width is what limits)."""
    look_at = (points.min(axis=0) + points.max(axis=0)) / 2
    radius = max(float(np.linalg.norm(points - look_at, axis=1).max()), 0.1)
    side = np.subtract(INITIAL_VIEW_POSITION_M, INITIAL_VIEW_LOOK_AT_M)
    half_angle = min(fov_rad / 2, math.atan(math.tan(fov_rad / 2) * aspect))
    distance = OVERVIEW_MARGIN * radius / np.sin(half_angle)
    return look_at + distance * side / np.linalg.norm(side), look_at


def frustum_shape(width_px: int, height_px: int, K: np.ndarray) -> tuple[float, float]:
    """viser frustum (vertical fov in radians, aspect width/height) for an image and its intrinsics."""
    return 2.0 * math.atan2(height_px / 2.0, K[1, 1]), width_px / height_px


def frustum_image_plane(fov: float, aspect: float, scale: float) -> tuple[float, float, float]:
    """(half width, half height, depth) in metres, camera frame, of the photo viser draws on a frustum.

    viser normalises each frustum to a fixed volume before applying `scale`
    (CameraFrustumVariants.tsx): with v = ∛(tan²(fov/2)·aspect/3) the image plane sits at depth
    scale/v and spans ±scale·tan(fov/2)·aspect/v by ±scale·tan(fov/2)/v.
    """
    tan = math.tan(fov / 2.0)
    volume = (tan * tan * aspect / 3.0) ** (1.0 / 3.0)
    return scale * tan * aspect / volume, scale * tan / volume, scale / volume


def frustum_scale(fov: float, aspect: float, plane_width_m: float) -> float:
    """The `scale` at which viser draws a frustum's photo `plane_width_m` wide."""
    return plane_width_m / (2.0 * frustum_image_plane(fov, aspect, 1.0)[0])


def image_plane_points(uv: np.ndarray, width_px: int, height_px: int, fov: float, aspect: float,
                       scale: float) -> np.ndarray:
    """(N, 2) image pixels -> (N, 3) points in the camera frame, metres, on the frustum's drawn photo.

    The photo fills the frustum's image plane edge to edge, so a pixel maps linearly onto it
    (exact for a centred principal point and square pixels, which the frustum drawing assumes).
    """
    half_w, half_h, depth = frustum_image_plane(fov, aspect, scale)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    x = (2.0 * uv[:, 0] / width_px - 1.0) * half_w
    y = (2.0 * uv[:, 1] / height_px - 1.0) * half_h
    return np.column_stack([x, y, np.full(len(uv), depth)])


def fit_width(image: np.ndarray, max_width: int) -> np.ndarray:
    """`image` as RGB uint8, shrunk (aspect kept) to at most `max_width` px wide; BGR or gray in."""
    rgb = cv2.cvtColor(image, cv2.COLOR_GRAY2RGB if image.ndim == 2 else cv2.COLOR_BGR2RGB)
    h, w = rgb.shape[:2]
    if w <= max_width:
        return rgb
    return cv2.resize(rgb, (max_width, max(1, round(h * max_width / w))), interpolation=cv2.INTER_AREA)


def linked_groups(n: int, linked: Callable[[int, int], bool]) -> list[list[int]]:
    """0 … n-1 grouped so that each is `linked(i, j)` (j < i) to another in its group (single
    linkage); the groups in order of their first index, each in order."""
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(n):
        for j in range(i):
            if linked(i, j):
                parent[root(i)] = root(j)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(i)
    return list(groups.values())


def label_groups(positions: list[np.ndarray], radius_m: float) -> list[list[int]]:
    """Indices into `positions` ((3,) metres each) grouped so that each stands within `radius_m` of
    another in its group (single linkage); the groups in order of their first index, each in order."""
    return linked_groups(len(positions), lambda i, j: bool(
        np.linalg.norm(np.asarray(positions[i]) - np.asarray(positions[j])) < radius_m))


def label_size_px(text: str) -> tuple[float, float]:
    """(width, height) on screen, CSS px, of the label viser draws for `text` (lines split at "\n"):
    an upper bound for the fonts viser's labels use."""
    width = max(sum(LABEL_WIDEST_PX if c in LABEL_WIDEST or not c.isascii() else LABEL_NARROW_PX if c in LABEL_NARROW
                    else LABEL_WIDE_PX if c.isupper() or c == "w" else LABEL_CHAR_PX for c in line)
                for line in text.split("\n"))
    pad = 0.2 * LABEL_LINE_PX
    return width + pad, LABEL_LINE_PX * (text.count("\n") + 1) + pad


@dataclass(frozen=True)
class View:
    """Where a viewer sees things, in the CSS px its labels are sized in (`label_size_px`): `px`
    (N, 2) of each camera in its canvas, `width` × `height` px."""

    px: np.ndarray
    width: float
    height: float

    @staticmethod
    def of(camera: viser.CameraHandle, points: np.ndarray, px_per_css_px: float = 1.0) -> View:
        """Where the viewer with `camera` sees `points` (N, 3) m, its canvas (reported in device
        px, `screen_px`) drawn at `px_per_css_px` device px to the CSS px."""
        return View(screen_px(points, camera) / px_per_css_px, camera.image_width / px_per_css_px,
                    camera.image_width / camera.aspect / px_per_css_px)


def screen_px(points: np.ndarray, camera: viser.CameraHandle) -> np.ndarray:
    """(N, 2) px in the canvas of a viewer's `camera` of `points` (N, 3) m; NaN for those behind it.

    Canvas px as the viewer reports its size: device pixels (the canvas' width and height in
    viser's client), as many to the CSS px as the screen has, or fewer while viser lowers its
    resolution to keep its frame rate.
    """
    forward = np.asarray(camera.look_at, float) - camera.position
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, camera.up_direction)
    right /= np.linalg.norm(right)
    local = (np.asarray(points, float).reshape(-1, 3) - camera.position) @ np.stack(
        [right, np.cross(forward, right), forward], axis=1)   # OpenCV axes: x right, y down, z ahead
    height = camera.image_width / camera.aspect
    focal = height / 2 / math.tan(camera.fov / 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        px = focal * local[:, :2] / local[:, 2:] + [camera.image_width / 2, height / 2]
    px[local[:, 2] <= 0] = np.nan
    return px


# How far a label's box stands left of and above its anchor, in widths and heights: viser's anchors
# name the box's corner or edge at it ("top-left": the box rightward and down).
ANCHOR_SHIFT = {"left": 0.0, "top": 0.0, "center": 0.5, "right": 1.0, "bottom": 1.0}


@dataclass(frozen=True)
class SharedLabel:
    """One label: written from camera `at` (an index), it names `cameras` (indices, in order) in
    `text`; `anchor` is the corner of its box at the camera, as viser's labels are anchored."""

    at: int
    cameras: list[int]
    text: str
    anchor: Anchor = "top-left"

    def box(self, view: View) -> tuple[float, float, float, float]:
        """(left, top, right, bottom) px on `view`'s screen; NaN when its camera is behind the viewer."""
        (x, y), (width, height) = view.px[self.at], label_size_px(self.text)
        vertical, horizontal = self.anchor.split("-")
        left, top = x - width * ANCHOR_SHIFT[horizontal], y - height * ANCHOR_SHIFT[vertical]
        return left, top, left + width, top + height

    def beyond(self, view: View) -> float:
        """How far, px, it reaches past `view`'s screen less LABEL_EDGE_PX at each edge (0 when its
        camera is behind the viewer)."""
        left, top, right, bottom = self.box(view)
        if not np.isfinite(left):
            return 0.0
        edge = LABEL_EDGE_PX
        return (max(0.0, edge - left) + max(0.0, edge - top) + max(0.0, right - view.width + edge)
                + max(0.0, bottom - view.height + edge))

    def fits(self, view: View) -> bool:
        """Whether it is drawn whole on `view`'s screen, clear of its edges (`beyond`), or not at all:
        its camera behind the viewer."""
        return self.beyond(view) == 0


# A corner or side of a label's box, as viser anchors labels.
Anchor = Literal["top-left", "top-center", "top-right", "center-left", "center-center", "center-right",
                 "bottom-left", "bottom-center", "bottom-right"]
# Where a label may be written from, as (camera, anchor) in the order tried; a camera's own as viser
# writes it, rightward and down from it, else leftward, or up from it, or centred on it, to stay inside
# the view. A group's from its camera highest, lowest or in the middle on the screen, as a camera's.
OVER: tuple[tuple[str, Anchor], ...] = (("top", "top-left"), ("top", "top-right"), ("bottom", "bottom-left"), ("bottom", "bottom-right"),
        ("middle", "center-left"), ("middle", "center-right"), ("top", "top-center"), ("bottom", "bottom-center"),
        ("middle", "center-center"))
# A group's beside its cameras, covering none of them, where it fits (written down from the highest, the
# list ran over the others): left of the leftmost, above the highest, right of the rightmost, below the
# lowest. Left first: a camera's own label runs rightward, and viser's own page has its control panel
# over the right of the view.
BESIDE: tuple[tuple[str, Anchor], ...] = (
    ("left", "center-right"), ("top", "bottom-left"), ("top", "bottom-right"), ("top", "bottom-center"),
    ("right", "center-left"), ("bottom", "top-left"), ("bottom", "top-right"), ("bottom", "top-center"))


def label_texts(texts: list[str]) -> list[str]:
    """What a label of cameras whose own texts are `texts` may say, in the order tried: every text, one
    a line, then more a line (in the 3D strip under the images, some 300 px high, twenty names one a line
    ran past its bottom); for more than MAX_TEXTS_LISTED, how many and the first and last text, on one
    line or three."""
    if len(texts) > MAX_TEXTS_LISTED:
        count, first, last = f"{len(texts)} cameras:", texts[0], texts[-1]
        return [f"{count} {first} ... {last}", f"{count}\n{first} ...\n{last}"]
    return ["\n".join(LABEL_SEPARATOR.join(texts[i:i + per_line]) for i in range(0, len(texts), per_line))
            for per_line in range(1, len(texts) + 1)]


def group_roles(group: list[int], view: View | None) -> dict[str, int]:
    """The cameras of `group` (indices) highest ("top"), lowest, in the middle, leftmost and rightmost on
    `view`'s screen (its first camera for each when there is no view or none of them is in front of it)."""
    px = {i: view.px[i] for i in group if np.isfinite(view.px[i]).all()} if view else {}
    if not px:
        return dict.fromkeys(("top", "middle", "bottom", "left", "right"), group[0])
    by_y = sorted(px, key=lambda i: px[i][1])
    return {"top": by_y[0], "middle": by_y[len(by_y) // 2], "bottom": by_y[-1],
            "left": min(px, key=lambda i: px[i][0]), "right": max(px, key=lambda i: px[i][0])}


def shared_label(group: list[int], texts: list[str], views: list[View]) -> SharedLabel:
    """The label of `group` (indices into `texts`, each camera's own text; `labels_apart`' views),
    saying what `label_texts` gives from where `BESIDE` and `OVER` say, its cameras placed on the first
    viewer's screen: the first drawn whole on every viewer's screen, trying every text beside a group's
    cameras before any over them; when none is drawn whole, the one that reaches least past the edges."""
    roles = group_roles(group, views[0] if views else None)
    best, least = None, math.inf
    for places in ((BESIDE, OVER) if len(group) > 1 else (OVER,)):
        for text in label_texts([texts[i] for i in group]):
            for role, anchor in places:
                label = SharedLabel(roles[role], group, text, anchor)
                beyond = sum(label.beyond(view) for view in views)
                if beyond == 0:
                    return label
                if beyond < least:
                    best, least = label, beyond
    return best


def labels_apart(groups: list[list[int]], texts: list[str], views: list[View]) -> list[SharedLabel]:
    """The labels of cameras whose own label texts are `texts`, `groups` of them (indices, as
    `label_groups` gives them) sharing one, merged until no two overlap on any of the viewers'
    screens (`views`, where each camera is seen: `View`): a label lists its group's texts, or counts
    them, written from one of its cameras (`shared_label`). In order of their first camera."""
    while True:
        labels = [shared_label(group, texts, views) for group in groups]
        b = np.asarray([[label.box(view) for view in views] for label in labels], float).reshape(
            len(labels), len(views), 4)   # left, top, right, bottom
        # NaN (behind a viewer) compares false: such a label overlaps nothing on that screen.
        overlap = np.any((b[:, None, :, 0] < b[None, :, :, 2] + LABEL_GAP_PX)
                         & (b[None, :, :, 0] < b[:, None, :, 2] + LABEL_GAP_PX)
                         & (b[:, None, :, 1] < b[None, :, :, 3] + LABEL_GAP_PX)
                         & (b[None, :, :, 1] < b[:, None, :, 3] + LABEL_GAP_PX), axis=2)
        merged = linked_groups(len(groups), lambda i, j: bool(overlap[i, j]))
        if len(merged) == len(groups):
            return labels
        groups = [sorted(i for k in parts for i in groups[k]) for parts in merged]


def label_rgb(library: Library, label: str) -> tuple[int, int, int]:
    """A colour per library sign, stable while the library's order is."""
    return LABEL_RGB[library.ids.index(label) % len(LABEL_RGB)]


# --------------------------------------------------------------------------- settings panel

@dataclass
class SettingControl:
    """The GUI input(s) of one setting; `enabled` is the checkbox of a nullable one (unticked = None)."""

    name: str
    input: viser.GuiInputHandle
    enabled: viser.GuiCheckboxHandle | None = None

    @property
    def value(self) -> Any:
        return None if self.enabled is not None and not self.enabled.value else self.input.value

    def show(self, value: Any) -> None:
        """Display `value`; fires the inputs' on_update callbacks (the panel's guard silences them)."""
        if self.enabled is not None:
            # viser sets `value` through its props machinery, which its type hints do not show.
            self.enabled.value = value is not None  # type: ignore[misc]
            self.input.disabled = value is None
            if value is None:
                return
        self.input.value = value  # type: ignore[misc]


@dataclass
class SettingsPanel:
    """One GUI folder per settings group, one control per field of `settings_schema()`.

    User edits call `on_change({name: value})`; `show()` displays settings from elsewhere
    without calling it, so a settings event never echoes back as a change.
    """

    controls: dict[str, SettingControl]
    on_change: Callable[[dict[str, Any], viser.ClientHandle | None], None] = field(repr=False)
    version: int = -1
    _quiet: threading.local = field(default_factory=threading.local, repr=False)

    def show(self, settings: dict[str, Any], version: int | None = None) -> None:
        """Display `settings` (name -> value); an event older than the one shown is ignored."""
        if version is not None:
            if version < self.version:
                return
            self.version = version
        # viser runs on_update synchronously in the assigning thread, so a thread-local flag
        # silences exactly our own assignments and never a user's edit arriving meanwhile.
        self._quiet.active = True
        try:
            for name, value in settings.items():
                if name in self.controls:
                    self.controls[name].show(value)
        finally:
            self._quiet.active = False

    def _edited(self, control: SettingControl, event: viser.GuiEvent) -> None:
        if getattr(self._quiet, "active", False):
            return
        if control.enabled is not None:
            control.input.disabled = not control.enabled.value
            if event.target is control.input and not control.enabled.value:
                return  # the value is staged until the checkbox turns it on
        self.on_change({control.name: control.value}, event.client)


def add_settings_panel(gui: viser.GuiApi, settings: Settings,
                       on_change: Callable[[dict[str, Any], viser.ClientHandle | None], None]) -> SettingsPanel:
    """Build the settings folders showing `settings`; edits are reported to `on_change(changes, client)`."""
    panel = SettingsPanel({}, on_change)
    current = settings.to_dict()
    groups: dict[str, list[dict]] = {}
    for entry in settings_schema():
        groups.setdefault(entry["group"], []).append(entry)
    for group, entries in groups.items():
        with gui.add_folder(group, expand_by_default=False):
            for entry in entries:
                control = _add_control(gui, entry, current[entry["name"]])
                for handle in (control.input, control.enabled):
                    if handle is not None:
                        handle.on_update(functools.partial(panel._edited, control))
                panel.controls[entry["name"]] = control
    return panel


def _add_control(gui: viser.GuiApi, entry: dict, value: Any) -> SettingControl:
    name, kind, hint = entry["name"], entry["type"], entry.get("help")
    if kind == "choice":
        return SettingControl(name, gui.add_dropdown(name, tuple(entry["choices"]), initial_value=value, hint=hint))
    if kind == "bool":
        return SettingControl(name, gui.add_checkbox(name, bool(value), hint=hint))
    cast = int if kind == "int" else float
    lo, hi = cast(entry["min"]), cast(entry["max"])
    step = cast(entry.get("step") or (1 if kind == "int" else (hi - lo) / 100))
    enabled = None
    if entry.get("nullable"):
        enabled = gui.add_checkbox(f"{name} on", value is not None, hint=f"Untick for none. {hint}")
    # A null value shows the top of the range: turning the checkbox on then sends a valid value.
    shown = cast(hi if value is None else value)
    if (hi - lo) / step > MAX_SLIDER_POSITIONS:
        number = gui.add_number(name, shown, min=lo, max=hi, step=step, hint=hint, disabled=value is None)
    else:
        number = gui.add_slider(name, lo, hi, step, shown, hint=hint, disabled=value is None)
    return SettingControl(name, number, enabled)


# --------------------------------------------------------------------------- scene

@dataclass
class SignNodes:
    """One sign's world: `frame` is the sign frame (axes), `plane` the sign texture at its physical size,
    `outline` its edges (a white plaque is otherwise lost against viser's white background)."""

    frame: viser.FrameHandle
    plane: viser.ImageHandle
    outline: viser.LineSegmentsHandle

    def remove(self) -> None:
        self.outline.remove()
        self.plane.remove()
        self.frame.remove()


@dataclass
class CameraNodes:
    """What one recognised image shows in its sign's world, and the recognition it shows."""

    sign: str
    recognition: Recognition
    frustum: viser.CameraFrustumHandle
    label: viser.LabelHandle
    matches: viser.LineSegmentsHandle
    text: str   # its own label text; its label may list others' too (`_share_labels`)

    def remove(self) -> None:
        self.matches.remove()
        self.label.remove()
        self.frustum.remove()


@dataclass
class SceneHandle:
    """Everything `attach` added to a viser server; `close()` detaches from the workspace.

    `signs` and `cameras` (keyed by image id) mirror the workspace as of the last `redraw()`, and
    `_shown` lists the cameras it drew, whose labels `relayout_labels()` lays out again.
    """

    server: viser.ViserServer
    workspace: Workspace
    panel: SettingsPanel
    world: viser.GuiDropdownHandle
    show_matches: viser.GuiCheckboxHandle
    frustum_width: viser.GuiSliderHandle
    status: viser.GuiMarkdownHandle
    upload: viser.GuiUploadButtonHandle
    signs: dict[str, SignNodes] = field(default_factory=dict)
    cameras: dict[str, CameraNodes] = field(default_factory=dict)
    _thumbnails: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    # By client id, from the viewer's first camera report (its canvas size): (position, look_at) in m
    # of the view it was last framed to, kept while its camera stays there (the person has not moved
    # it), so it follows the cameras drawn; None while it has not been framed on cameras.
    _framed: dict[int, tuple[np.ndarray, np.ndarray] | None] = field(default_factory=dict, repr=False)
    _progress: dict[str, Any] = field(default_factory=dict, repr=False)
    # By client id, the CSS px width of the viewer's canvas as its page last said (`set_canvas_width`):
    # viser reports canvases in device px and draws labels at a size in CSS px.
    _css_width: dict[int, float] = field(default_factory=dict, repr=False)
    # The viewers whose control panel `fold_panel_in_small_view` has been asked about, by client id.
    _panel_checked: set[int] = field(default_factory=set, repr=False)
    _shown: list[tuple[ImageRecord, Recognition]] = field(default_factory=list, repr=False)
    _lock: threading.RLock = field(default_factory=threading.RLock, repr=False)
    # Set when the scene is stale (`_mark_stale`) or closed; `_stale_all` says whether more than the
    # labels' layout is stale.
    _dirty: threading.Event = field(default_factory=threading.Event, repr=False)
    _stale_all: bool = False
    _closed: bool = False
    _stale_geometry: bool = False
    _stale_signs: bool = False
    _unsubscribe: Callable[[], None] | None = field(default=None, repr=False)
    _thread: threading.Thread | None = field(default=None, repr=False)
    # The flights' trajectories (app/flight_scene.py), None for a scene without flights; redrawn when
    # the (id, result_version) of the flights held, last seen in `_flight_runs`, change.
    flight_layer: FlightLayer | None = None
    _flight_runs: tuple = ()
    # The sign map's world (app/map_scene.py), None for a scene without a map holder; `_show_map` is
    # set when a map comes to be held, which the next redraw then shows.
    map_layer: MapLayer | None = None
    _show_map: bool = False

    # ---- lifecycle

    def _start(self) -> None:
        self._unsubscribe = self.workspace.subscribe(self._on_event)
        self._thread = threading.Thread(target=self._redraw_loop, name="signpose-scene", daemon=True)
        self._thread.start()
        self._mark_stale()

    def close(self) -> None:
        """Stop following the workspace; the viser nodes stay as they are. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        if self._unsubscribe is not None:
            self._unsubscribe()
        self._dirty.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)

    def _mark_stale(self, labels_only: bool = False) -> None:
        """Have the redraw thread bring the scene up to date: all of it, or only the labels' layout."""
        if not labels_only:
            self._stale_all = True
        self._dirty.set()

    def _redraw_loop(self) -> None:
        while True:
            self._dirty.wait()
            if self._closed:
                return
            self._dirty.clear()
            # Reset only once read as set: a mark coming between the two is then drawn by this
            # redraw, which reads the workspace after it.
            everything = self._stale_all
            if everything:
                self._stale_all = False
            try:
                if everything:
                    self.redraw()
                else:
                    self.relayout_labels()
            except Exception:  # a bad record must not stop later redraws
                log.exception("scene redraw failed")
            # Events arriving during this pause fold into a single next redraw.
            time.sleep(REDRAW_INTERVAL_S)

    def _on_event(self, event: Event) -> None:
        if event.kind == "settings":
            self.panel.show(event.payload["settings"], event.payload["version"])
            return
        if event.kind == "calibration":   # nothing drawn depends on it: a board search would redraw a photo at a time
            return
        if event.kind == "flight_cursor":
            self._follow_cursor(event.payload["id"])
            return
        if event.kind == "flights":   # progress while a flight runs changes nothing drawn until it ends
            runs = tuple((f["id"], f["result_version"]) for f in event.payload["flights"])
            if runs == self._flight_runs:
                return
            self._flight_runs = runs
        if event.kind == "map":
            self._show_map = self.map_layer is not None and self.map_layer.held is not None
        if event.kind == "results":
            self._progress = event.payload
        elif event.kind == "library":
            self._stale_signs = True
        self._mark_stale()

    # ---- user actions

    def _apply_settings(self, changes: dict[str, Any], client: viser.ClientHandle | None) -> None:
        try:
            self.workspace.update_settings(changes)
        except SettingsError as exc:
            self.panel.show(self.workspace.settings.to_dict())
            if client is not None:
                client.add_notification("Setting not applied", str(exc), color="red", auto_close_seconds=8.0)
            log.info("setting not applied: %s", exc)

    def _on_upload(self, event: viser.GuiEvent) -> None:
        file = event.target.value
        try:
            self.workspace.add_image(file.name, file.content, None)
        except ValueError as exc:  # ImageError and friends: messages meant for the user
            if event.client is not None:
                event.client.add_notification("Image not added", str(exc), color="red", auto_close_seconds=8.0)
            log.info("upload %s rejected: %s", file.name, exc)

    def _on_upload_refused(self, client_id: int, why: str) -> None:
        """viser's event loop calls this: queue the notice, no more."""
        client = self.server.get_clients().get(client_id)
        if client is not None:
            client.add_notification("Image not added", why, color="red", auto_close_seconds=8.0)
        log.info("upload refused: %s", why)

    def _follow_cursor(self, flight_id: str) -> None:
        """Move the flight's current frustum to the frame the page shows, in the map world and in the
        world of a sign that frame sees (switching worlds when the one shown is a sign's that does not see it)."""
        if self.flight_layer is None:
            return
        with self._lock:
            if self.map_layer is not None:
                self.map_layer.show_cursor(flight_id)
            self.flight_layer.show_cursor(flight_id)
            if self.world.value == MAP_WORLD:
                return
            worlds = self.flight_layer.cursor_labels(flight_id)
            if worlds and self.world.value not in worlds and worlds[0] in self.world.options:
                self.world.value = worlds[0]  # type: ignore[misc]
                self._on_view_option()

    def _on_view_option(self, _event: viser.GuiEvent | None = None) -> None:
        with self._lock:
            for sign_id, nodes in self.signs.items():
                nodes.frame.visible = sign_id == self.world.value
            if self.map_layer is not None:
                self.map_layer.root.visible = self.world.value == MAP_WORLD
            for nodes in self.cameras.values():
                nodes.matches.visible = self.show_matches.value
            self._frame_world()

    def _on_world(self, event: viser.GuiEvent | None = None) -> None:
        """Show the world chosen; its labels are laid out in the viewers' views on the redraw thread
        (those of a world not shown are not)."""
        self._on_view_option(event)
        self._mark_stale(labels_only=True)

    def _overview(self, fov_rad: float, aspect: float) -> tuple[np.ndarray, np.ndarray] | None:
        """`overview_camera` of the shown sign and its cameras; None without a sign. The caller
        holds the lock."""
        if self.world.value == MAP_WORLD and self.map_layer is not None:
            mapped = self.map_layer.points()
            return overview_camera(np.vstack(mapped), fov_rad, aspect) if mapped else None
        sign = self.signs.get(self.world.value)
        if sign is None:
            return None
        flown = self.flight_layer.points(self.world.value) if self.flight_layer is not None else []
        points = np.vstack([np.asarray(sign.outline.points).reshape(-1, 3),
                            *[np.asarray(n.frustum.position).reshape(1, 3)
                              for n in self.cameras.values() if n.sign == self.world.value], *flown])
        return overview_camera(points, fov_rad, aspect)

    def _label_px(self) -> float:
        """CSS px of the widest camera's own label text in the shown world: not of the labels as
        shared, which are laid out in the views framed with this. The caller holds the lock."""
        return max((label_size_px(n.text)[0] for n in self.cameras.values() if n.sign == self.world.value),
                   default=0)

    def _frame_world(self) -> None:
        """Point new viewers' and Reset View's camera at the shown sign and its cameras, and the
        viewers' not yet framed on cameras or still where they were framed; a viewer the person has
        moved is left where it is. The caller holds the lock."""
        initial = self.server.initial_camera
        view = self._overview(initial.fov, 1.0)
        if view is None:
            # Nothing to look at: wherever a viewer is, the first cameras drawn are framed for it,
            # as on a page opened then (an empty workspace, the default at the start of a round).
            self._framed = dict.fromkeys(self._framed)
            return
        if not (np.allclose(initial.position, view[0]) and np.allclose(initial.look_at, view[1])):
            initial.position, initial.look_at = view
        for client in self.server.get_clients().values():
            if self._follows(client):
                self.frame_for(client)

    def _follows(self, client: viser.ClientHandle) -> bool:
        """Whether `client` is framed as cameras come and go: its canvas is known and it has not been
        framed on cameras yet, or its camera is where `frame_for` last put it, within the rounding
        of its reports. The caller holds the lock."""
        if client.client_id not in self._framed:
            return False
        framed = self._framed[client.client_id]
        return framed is None or all(np.allclose(now, then, atol=FRAMED_TOLERANCE_M)
                                     for now, then in zip((client.camera.position, client.camera.look_at), framed))

    def frame_for(self, client: viser.ClientHandle) -> None:
        """Point `client`'s camera at the shown sign and its cameras within its own canvas. The
        initial camera fits them in a square's height; a canvas narrower than tall (the page's 3D
        column) is framed for its width, which the square's framing cuts at the sides, less the
        width of the widest label either side: a camera at the edge has its label beside it."""
        camera = client.camera
        with self._lock:
            css_width = camera.image_width / self._px_per_css_px_of(client)
            # at least a quarter of the width: labels wider than that cannot be helped by zooming out
            room = max(0.25, 1.0 - 2.0 * (self._label_px() + LABEL_EDGE_PX) / css_width)
            view = self._overview(camera.fov, min(camera.aspect * room, 1.0))
            framed = self._framed.get(client.client_id)
            # Every redraw comes here for the viewers left where they were framed: send changes only.
            if view is None or framed is not None and all(np.allclose(a, b) for a, b in zip(view, framed)):
                return
            self._framed[client.client_id] = view
        with client.atomic():
            camera.position, camera.look_at = view

    def _viewers(self) -> list[viser.ClientHandle]:
        """The viewers connected that have reported their camera (`_framed` holds them). The caller
        holds the lock."""
        return [c for c in self.server.get_clients().values() if c.client_id in self._framed]

    def _on_connect(self, client: viser.ClientHandle) -> None:
        """Frame a new viewer's canvas once its size is known: its first camera report. As its view
        moves, its labels are laid out again (`relayout_labels`), on the redraw thread."""

        def on_camera(_camera: viser.CameraHandle) -> None:
            with self._lock:
                first = client.client_id not in self._framed
                self._framed.setdefault(client.client_id, None)
            if first:
                self.frame_for(client)
            # Every report, not the first only: a view laid out as it loads reports a size it then leaves.
            self._fold_panel_once(client)
            self._mark_stale(labels_only=True)

        client.camera.on_update(on_camera)
        # viser calls this on its thread pool once the first camera report is in, and hands that
        # report to the callbacks registered by then: on a busy machine, before this one. A view
        # that never moves reports no more, and would be neither framed nor its panel folded.
        on_camera(client.camera)

    def _on_disconnect(self, client: viser.ClientHandle) -> None:
        with self._lock:
            self._framed.pop(client.client_id, None)
            self._css_width.pop(client.client_id, None)
            self._panel_checked.discard(client.client_id)

    def set_canvas_width(self, client_id: int, css_px: float) -> None:
        """Note that viewer `client_id`'s canvas is `css_px` CSS px wide (its page says so: viser
        does not); it is framed at once, and the labels laid out again. Kept by viewer, not by the canvas'
        size in device px: two screens' canvases of one size can be of two sizes in CSS px (a phone
        of 2 device px to the CSS px beside a laptop of 1), and a window zoomed keeps its device px."""
        with self._lock:
            client = self.server.get_clients().get(client_id)
            was = self._css_width.get(client_id)
            if client is None or was == css_px:
                return   # gone, so never to be forgotten on disconnect; or nothing new
            self._css_width[client_id] = css_px
            if was is not None and (was < SHEET_BELOW_PX) != (css_px < SHEET_BELOW_PX):
                self._panel_checked.discard(client_id)   # viser builds its panel anew, open
            # Framed at its scale now, before the page's request is answered, not on the redraw thread
            # after it: a busy redraw would leave the view framed for the wrong scale meanwhile.
            if self._follows(client):
                self.frame_for(client)
        self._fold_panel_once(client)
        self._mark_stale()

    def _fold_panel_once(self, client: viser.ClientHandle) -> None:
        """`fold_panel_in_small_view` for `client` once both its canvas' size in CSS px and its
        camera (the canvas' aspect) are known, whichever comes last, until the view is small enough
        to fold it; once a viewer, and again as its view crosses viser's phone breakpoint, so a
        panel the person opened stays open."""
        with self._lock:
            css_width = self._css_width.get(client.client_id)
            if css_width is None or client.client_id not in self._framed or client.client_id in self._panel_checked:
                return
            if not panel_covers_view(client, css_width):
                return
            self._panel_checked.add(client.client_id)
        fold_panel_in_small_view(client, css_width)

    def _px_per_css_px_of(self, client: viser.ClientHandle) -> float:
        """Device px to the CSS px of `client`'s canvas: the device px its camera last reported over the
        CSS px its page last said, as viser lowers its resolution without a camera report (its page's
        device px may be newer than the camera's; its CSS px stay). 1 until its page has said. The
        caller holds the lock."""
        css_px = self._css_width.get(client.client_id)
        return 1.0 if css_px is None else client.camera.image_width / css_px

    def _on_frustum_width(self, _event: viser.GuiEvent) -> None:
        self._stale_geometry = True
        self._mark_stale()

    def view_from(self, image_id: str, client: viser.ClientHandle) -> None:
        """Move `client`'s viewport to the estimated camera of `image_id`, looking along its optical axis,
        and name it there: among cameras sharing a label (or counted in one), nothing else says which
        frustum was clicked."""
        with self._lock:
            nodes = self.cameras.get(image_id)
            if nodes is None:
                return
            if self.world.value != nodes.sign:
                self.world.value = nodes.sign  # type: ignore[misc]
            position, wxyz = np.asarray(nodes.frustum.position), np.asarray(nodes.frustum.wxyz)
            text = nodes.text
        axes = tf.SO3(wxyz).as_matrix()
        forward = axes[:, 2]
        # Orbit around where the optical axis meets the sign plane (z = 0); a camera facing away
        # from it orbits a point as far ahead as the camera is from the sign.
        meets_sign = position[2] < 0 < forward[2]
        depth = -position[2] / forward[2] if meets_sign else max(float(np.linalg.norm(position)), 1.0)
        with client.atomic():
            client.camera.position = position
            client.camera.look_at = position + depth * forward
            client.camera.up_direction = -axes[:, 1]
        client.add_notification(text, "the view from this camera (Reset View goes back)",
                                auto_close_seconds=CLICKED_NOTE_S)

    # ---- drawing

    def redraw(self) -> None:
        """Bring the viser scene in line with the workspace's current images and results."""
        with self._lock:
            library = self.workspace.library
            records = self.workspace.images()
            # Each outcome read once: a re-run replaces a record's outcome while this runs.
            outcomes = [r.outcome for r in records]
            shown = [(r, o.recognition) for r, o in zip(records, outcomes)
                     if _has_pose(o.recognition) and o.recognition.label in library.ids]
            counts = Counter(rec.label for _, rec in shown)
            # A flight's signs have a world too, ranked after every sign a photo shows.
            for label in self.flight_layer.labels() & set(library.ids) if self.flight_layer is not None else ():
                counts[label] += 0
            stale_geometry, self._stale_geometry = self._stale_geometry, False
            if self._stale_signs:
                # Library edits can change a sign's image or size under the same id.
                self._stale_signs = False
                self._remove_cameras(set(self.cameras))
                if self.flight_layer is not None:
                    self.flight_layer.clear()
                if self.map_layer is not None:
                    self.map_layer.clear()
                self._remove_signs(set(self.signs))
            if self.flight_layer is not None:
                self.flight_layer.prune(library)

            current = {r.id for r in records}
            self._thumbnails = {k: v for k, v in self._thumbnails.items() if k in current}
            sign_of = {r.id: rec.label for r, rec in shown}
            self._remove_cameras({k for k, nodes in self.cameras.items() if sign_of.get(k) != nodes.sign})
            self._remove_signs(set(self.signs) - set(counts))
            for sign_id in counts:
                if sign_id not in self.signs:
                    self.signs[sign_id] = self._add_sign(library[sign_id])
            for record, rec in shown:
                nodes = self.cameras.get(record.id)
                if nodes is None or nodes.recognition is not rec or stale_geometry:
                    self._draw_camera(record, rec, library)
            if self.flight_layer is not None:
                self.flight_layer.draw(library, self.frustum_width.value, redraw_all=stale_geometry)
            if self.map_layer is not None:
                self.map_layer.draw(library, shown, self.frustum_width.value, redraw_all=stale_geometry)
            self._choose_world(counts)
            self._shown = shown
            self._share_labels(shown)   # laid out in the views as framed for the world chosen
            generation = self.workspace.snapshot.generation
            self.status.content = status_markdown(
                [status_of(r.expected, o, generation) for r, o in zip(records, outcomes)], outcomes, self._progress)

    def relayout_labels(self) -> None:
        """Lay the labels of the cameras the last `redraw()` drew out again in the viewers' views as
        they are now: all that a view moving changes."""
        with self._lock:
            self._share_labels(self._shown)

    def _share_labels(self, shown: list[tuple[ImageRecord, Recognition]]) -> None:
        """One label for each group of cameras in a sign's world standing closer than the drawn photo
        width: their frustums overlap, and a label each, at their centres, printed one name over
        another (the same photo uploaded twice, a burst). In the world shown, the groups whose labels
        would overlap on a viewer's screen share one too: a dozen cameras seen from a few metres in
        the page's narrow 3D column printed their names over each other. One camera's label lists
        every name, or counts them, beside the group (`shared_label`); the others' are hidden. The caller
        holds the lock; `shown` are the cameras drawn."""
        by_sign: dict[str, list[tuple[ImageRecord, Recognition]]] = {}
        for record, rec in shown:
            by_sign.setdefault(rec.label, []).append((record, rec))
        for sign, cameras in by_sign.items():
            nodes = [self.cameras[record.id] for record, _ in cameras]
            positions = np.array([n.frustum.position for n in nodes], float).reshape(-1, 3)
            texts = [_camera_text(*camera) for camera in cameras]
            for node, text in zip(nodes, texts):
                node.text = text
            views = [View.of(c.camera, positions, self._px_per_css_px_of(c)) for c in self._viewers()
                     ] if sign == self.world.value else []
            for label in labels_apart(label_groups(list(positions), self.frustum_width.value), texts, views):
                if nodes[label.at].label.text != label.text:
                    nodes[label.at].label.text = label.text
                if nodes[label.at].label.anchor != label.anchor:
                    nodes[label.at].label.anchor = label.anchor
                for i in label.cameras:
                    if nodes[i].label.visible != (i == label.at):
                        nodes[i].label.visible = i == label.at

    def _remove_cameras(self, image_ids: set[str]) -> None:
        for image_id in image_ids:
            self.cameras.pop(image_id).remove()

    def _remove_signs(self, sign_ids: set[str]) -> None:
        for sign_id in sign_ids:
            self.signs.pop(sign_id).remove()

    def _choose_world(self, counts: Counter) -> None:
        mapped = self.map_layer is not None and self.map_layer.held is not None
        options = (*sorted(counts), *((MAP_WORLD,) if mapped else ())) or (NO_WORLD,)
        if tuple(self.world.options) != options:
            keep = self.world.value if self.world.value in options else None
            self.world.options = options
            self.world.value = keep or (counts.most_common(1)[0][0] if counts else options[0])  # type: ignore[misc]
        # Cleared only once acted on: a map arriving while this redraw runs sets it again for the next one.
        if self._show_map and mapped:
            self.world.value = MAP_WORLD  # type: ignore[misc]
            self._show_map = False
        self.world.disabled = options == (NO_WORLD,)
        self._on_view_option()

    def _add_sign(self, sign: LibrarySign) -> SignNodes:
        return add_sign_nodes(self.server, f"/signs/{sign.id}", sign, visible=self.world.value == sign.id)

    def _draw_camera(self, record: ImageRecord, rec: Recognition, library: Library) -> None:
        sign = library[rec.label]
        width_px, height_px = rec.image_size
        fov, aspect = frustum_shape(width_px, height_px, rec.camera.K)
        scale = frustum_scale(fov, aspect, self.frustum_width.value)
        position, wxyz = camera_pose_in_sign(rec.pose.R, rec.pose.t)
        color = AMBIGUOUS_RGB if rec.pose.ambiguous else label_rgb(library, rec.label)
        old = self.cameras.get(record.id)
        if old is not None and old.frustum.fov == fov and old.frustum.aspect == aspect:
            # Same photo and shape: move the frustum instead of re-sending its image.
            frustum, label = old.frustum, old.label
            frustum.position, frustum.wxyz, frustum.color, frustum.scale = position, wxyz, color, scale
            old.matches.remove()  # its label's text is `_share_labels`' to set
        else:
            if old is not None:
                old.remove()
            frustum = self._add_frustum(record, rec.label, fov, aspect, scale, color, position, wxyz)
            label = self.server.scene.add_label(f"{frustum.name}/label", _camera_text(record, rec))
        sign_px, image_px = matched_points(rec, sign)
        on_sign = sign.to_metric(sign_px)
        on_photo = image_plane_points(image_px, width_px, height_px, fov, aspect, scale)
        on_photo_world = on_photo @ tf.SO3(wxyz).as_matrix().T + position
        matches = self.server.scene.add_line_segments(
            f"/signs/{rec.label}/matches/{record.id}", np.stack([on_sign, on_photo_world], axis=1), color,
            thickness=1.0, thickness_units="screen", visible=self.show_matches.value)
        self.cameras[record.id] = CameraNodes(rec.label, rec, frustum, label, matches, _camera_text(record, rec))

    def _add_frustum(self, record: ImageRecord, sign_id: str, fov: float, aspect: float, scale: float,
                     color: tuple[int, int, int], position: np.ndarray, wxyz: np.ndarray) -> viser.CameraFrustumHandle:
        thumbnail = self._thumbnails.get(record.id)
        if thumbnail is None:
            thumbnail = self._thumbnails[record.id] = fit_width(self.workspace.photo(record), THUMBNAIL_WIDTH_PX)
        frustum = self.server.scene.add_camera_frustum(
            f"/signs/{sign_id}/cameras/{record.id}", fov, aspect, scale=scale, color=color, image=thumbnail,
            thickness=2.0, thickness_units="screen", position=position, wxyz=wxyz)
        image_id = record.id
        frustum.on_click(lambda event: self.view_from(image_id, event.client))
        return frustum


def add_sign_nodes(server: viser.ViserServer, root: str, sign: LibrarySign, *, visible: bool = True,
                   wxyz: np.ndarray | tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0),
                   position: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0)) -> SignNodes:
    """`sign` drawn at `root`: its frame's axes (at `position`, m, turned by `wxyz` in the parent's
    frame), its image at its physical size and its outline."""
    size = max(sign.width_m, sign.height_m)
    frame = server.scene.add_frame(root, axes_length=0.5 * size, axes_radius=0.01 * size, visible=visible,
                                   wxyz=wxyz, position=position)
    plane = server.scene.add_image(f"{root}/plane", fit_width(sign.image, SIGN_TEXTURE_MAX_WIDTH_PX),
                                   sign.width_m, sign.height_m)
    corners = sign.to_metric(sign.corners_px)
    outline = server.scene.add_line_segments(
        f"{root}/outline", np.stack([corners, np.roll(corners, -1, axis=0)], axis=1), OUTLINE_RGB,
        thickness=2.0, thickness_units="screen")
    return SignNodes(frame, plane, outline)


def matched_points(rec: Recognition, sign: LibrarySign) -> tuple[np.ndarray, np.ndarray]:
    """(library px, image px), (N, 2) each, that tie the recognised `sign` to the photo.

    The RANSAC inliers when features decided; for the plaque fallback, which has no feature
    matches, the sign's corners and their image through the final H.
    """
    best = rec.best
    if best is not None:
        return best.src[best.estimate.inliers], best.dst[best.estimate.inliers]
    return sign.corners_px, rec.corners


def _has_pose(rec: Recognition | None) -> bool:
    return rec is not None and rec.recognized and rec.pose is not None


def _camera_text(record: ImageRecord, rec: Recognition) -> str:
    notes = []
    if rec.pose.ambiguous:
        notes.append("ambiguous pose")
    if is_correct(record.expected, rec) is False:
        notes.append(f"expected {record.expected}")
    return " · ".join([record.name, *notes])


def status_markdown(statuses: list[str], outcomes: list[Outcome], progress: dict[str, Any]) -> str:
    """One status line in the words of the page's top bar: image counts by `status_of`, median
    time per image and re-run progress."""
    counts = Counter(statuses)
    labelled = counts["correct"] + counts["wrong"]
    parts = [f"**{len(statuses)}** images"]
    if labelled:
        parts.append(f"**{counts['correct']}**/{labelled} correct")
    parts += [f"**{counts[s]}** {word}" for s, word in STATUS_WORDS.items() if counts[s]]
    recognitions = [o.recognition for o in outcomes if o.recognition is not None]
    if recognitions:
        reused = any(r.reused_stages for r in recognitions)
        parts.append(f"{statistics.median(r.timing_ms['total'] for r in recognitions):.0f} ms/image (median"
                     f"{', stages reused from cache' if reused else ''})")
    if progress.get("running"):
        parts.append(f"re-running {progress.get('done', 0)}/{progress.get('total', 0)}")
    return " · ".join(parts)


def name_viewer(client: viser.ClientHandle) -> None:
    """Tell `client`'s page the id of its viewer, which viser's client is not told: the page's
    canvas script (static/viser-canvas.js) names it when it says its canvas' size in CSS px, which
    is the viewer's own (`SceneHandle.set_canvas_width`)."""
    run_script(client, f"window.signposeViewer = {{ id: {int(client.client_id)} }};")


def panel_covers_view(client: viser.ClientHandle, css_width: float) -> bool:
    """Whether viser's control panel would cover much of `client`'s view, `css_width` CSS px wide
    (`FOLD_PANEL_BELOW_PX`): in the page, the 3D column at the side and the strip under the images."""
    return css_width < FOLD_PANEL_BELOW_PX[0] or css_width / client.camera.aspect < FOLD_PANEL_BELOW_PX[1]


def fold_panel_in_small_view(client: viser.ClientHandle, css_width: float) -> None:
    """Fold viser's control panel for `client`, whose canvas is `css_width` CSS px wide. viser shows
    it as a sheet at the bottom of a view narrower than its phone breakpoint, which no call of
    viser's folds (`fold_sheet`), else as a floating window."""
    if css_width < SHEET_BELOW_PX:
        fold_sheet(client)
    else:
        client.gui.main_panel.minimize()


def attach(server: viser.ViserServer, workspace: Workspace, flights: Flights | None = None,
           sign_maps: SignMaps | None = None) -> SceneHandle:
    """Add the sign/camera scene and the tuning GUI to `server` and keep both in step with `workspace`,
    with `flights`' trajectories when given, and with the map `sign_maps` holds in a world of its own."""
    from signpose.app.flight_scene import FlightLayer   # they draw with this module's helpers
    from signpose.app.map_scene import MapLayer

    server.scene.set_up_direction("-y")  # y runs down the sign
    server.initial_camera.position = INITIAL_VIEW_POSITION_M
    server.initial_camera.look_at = INITIAL_VIEW_LOOK_AT_M
    gui = server.gui
    status = gui.add_markdown("")
    upload = gui.add_upload_button("Add image", icon=viser.Icon.UPLOAD, mime_type="image/*",
                                   hint="Recognise a photo and add it to the workspace")
    with gui.add_folder("View"):
        world = gui.add_dropdown("Sign world", (NO_WORLD,), hint="Each sign is its own world: show this one, or "
                                                                 f"{MAP_WORLD}: every mapped sign in place",
                                 disabled=True)
        show_matches = gui.add_checkbox("Inlier matches", True,
                                        hint="Lines from each inlier on the sign to its pixel on the photo")
        frustum_width = gui.add_slider("Photo width (m)", 0.05, 2.0, 0.05, DEFAULT_FRUSTUM_WIDTH_M,
                                       hint="Drawn width of each camera's photo, in metres")
    # `scene` is bound below, before any client can connect and edit a setting.
    panel = add_settings_panel(gui, workspace.settings, lambda changes, client: scene._apply_settings(changes, client))
    panel.version = workspace.settings_version
    scene = SceneHandle(server, workspace, panel, world, show_matches, frustum_width, status, upload,
                        flight_layer=FlightLayer(server, flights) if flights is not None else None,
                        map_layer=(MapLayer(server, sign_maps, flights, workspace.signs_in_view)
                                   if sign_maps is not None else None))
    world.on_update(scene._on_world)
    show_matches.on_update(scene._on_view_option)
    frustum_width.on_update(scene._on_frustum_width)
    upload.on_upload(scene._on_upload)
    if not guard_uploads(server, max_bytes=workspace.config.max_upload_bytes, refused=scene._on_upload_refused):
        upload.disabled = True   # unbounded, and never freed if its client leaves halfway
    server.on_client_connect(scene._on_connect)
    server.on_client_connect(name_viewer)
    server.on_client_disconnect(scene._on_disconnect)
    scene._start()
    return scene
