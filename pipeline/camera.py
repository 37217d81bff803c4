"""Camera intrinsics: loading ROS (file or message) / OpenCV / Kalibr / plain-JSON camera files, and an assumed camera.

K is the OpenCV 3x3 matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels; `dist` is OpenCV's
(k1, k2, p1, p2[, k3, ...]) distortion vector.
"""

from __future__ import annotations

import codecs
import math
import re
import reprlib
from collections import Counter
from dataclasses import dataclass, field
from numbers import Integral, Real
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import yaml

from .image import resize_map
from .jsonfile import EMPTY_FILE, key_given_twice

ASSUMED_HFOV_DEG = 60.0
# Fields of view one may assume: rectilinear lenses from a long telephoto to an ultra-wide.
ASSUMED_HFOV_RANGE_DEG = (10.0, 140.0)

# Bounds no real camera violates, so that a typo, a unit mix-up or a file for another camera is
# refused where it is loaded rather than giving nonsense poses (or, far out, at fx = 1e100..1e300 px,
# a reprojection error of 1e100 px, LAPACK chatter on stdout, and an SVD that does not converge).
# A field of view under 0.1° is a telescope's: even the longest zoom a UAV carries sees several times
# wider. It is held against the image's longer side, as a crop to a thin strip is still a camera.
MIN_FOV_DEG = 0.1
# A pinhole camera's field of view across the image stays under 180°; the widest rectilinear
# lenses see about 130°, and a fisheye's calibrated fx (with its strong distortion) still puts
# its pinhole field under 150°. Beyond MAX_FOV_DEG a focal length was typed in mm (4.2 for a
# phone's lens, 1.4 cm from the sign instead of 1.4 m) or as a tiny number.
MAX_FOV_DEG = 170.0
# Without an image size, focal lengths and the principal point can only be held against a number:
# 1e6 px is 0.1° across 1745 px, and far beyond any sensor (the widest aerial cameras have under
# 30 000 px). A file for a longer lens gives its image size; for_image checks again against the image.
MAX_UNSIZED_PX = 1e6
# A calibrated principal point lies within a few percent of the image centre (lens decentring); a
# fifth of the width or height off means values in mm or a file for another resolution (one for
# twice the size puts it on this image's corner, half the width and height off; one for half the
# size a quarter off).
MAX_CENTRE_OFFSET = 0.2
# OpenCV holds an image's width and height in a C int: no image is larger.
MAX_IMAGE_SIDE_PX = 2**31 - 1
# Real pixels are square to a percent or two and anamorphic lenses squeeze 2x at most: fx/fy beyond
# 10 is a dropped digit or fx and fy from different cameras.
MAX_FOCAL_RATIO = 10.0
# Lens distortion moves the image corners by tens of percent at most (a strong wide-angle barrel
# about 40 %): distorted / undistorted radius beyond 5 or under 1/5 there is a typo or a model
# used far outside the images it was fitted to.
MAX_DISTORTION_FACTOR = 5.0
# Images a camera is scaled to keep its calibration's aspect within 1 % (sizes rounded to whole
# pixels at either resolution); beyond, the photo was cropped or re-framed.
MAX_ASPECT_CHANGE = 0.01

# The keys a camera file's numbers are read under. Every format (ROS camera_info file and message,
# OpenCV FileStorage, a Kalibr camchain's camera, signpose's JSON) is read with all of them, so that
# a file means the same whichever reader its syntax sends it to. Each is one of several names for
# one thing: a file that gives two of them is refused, as which it means cannot be known.
# The 3x3 camera matrix, row by row: ROS's file, ROS 2's and ROS 1's message, OpenCV's name.
MATRIX_KEYS = ("camera_matrix", "k", "K", "cameraMatrix")
# Kalibr gives the camera matrix as `intrinsics: [fu, fv, pu, pv]`, signpose's JSON as fx, fy, cx, cy.
# OpenCV's distortion vector (k1 k2 p1 p2 [k3 ...]): ROS's file, ROS 2's and ROS 1's message, the
# names OpenCV's functions and scripts use, Kalibr's, signpose's JSON.
DISTORTION_KEYS = ("distortion_coefficients", "d", "D", "dist_coeffs", "distCoeffs", "distortion_coeffs", "dist")
# The image size in px the intrinsics are for: ROS's file and OpenCV's calibration sample, then
# ROS's message and signpose's JSON; Kalibr's is `resolution: [width, height]`.
WIDTH_KEYS, HEIGHT_KEYS = ("image_width", "width"), ("image_height", "height")
# Keys that look like lens distortion or a lens model but are none of the keys read: refused, as
# ignoring them makes a distortion-free camera and poses off without a word (`dist_coef`,
# `distortion`, `k1`, a `fisheye` flag).
DISTORTION_LIKE = re.compile(r"distort|^dist(?!ance)|fisheye|^[kp]\d$", re.IGNORECASE)
# OpenCV's distortion model on a pinhole camera (k1 k2 p1 p2 [k3 ...]), by ROS's names for 5 and 8
# coefficients and Kalibr's ("radial-tangential") for 4.
OPENCV_DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "radtan")
# OpenCV's distortion vector by its length: its terms, and the distortion_model ROS or Kalibr names it
# (None: neither names it). Each model named has that many at most (fewer are OpenCV's with the rest
# 0, as plumb_bob's k1 k2 p1 p2 with k3 = 0); more are terms the model named has not.
COEFFICIENT_COUNTS = {4: ("k1 k2 p1 p2", "radtan"), 5: ("k1 k2 p1 p2 k3", "plumb_bob"),
                      8: ("k1 k2 p1 p2 k3 k4 k5 k6", "rational_polynomial"),
                      12: ("k1 ... k6 s1 s2 s3 s4, thin-prism terms", None),
                      14: ("k1 ... k6 s1 ... s4 tx ty, thin-prism and tilt terms", None)}
MODEL_COEFFICIENTS = {model: n for n, (_, model) in COEFFICIENT_COUNTS.items() if model}
# `distortion_model`s that name no distortion (ROS's field never set, Kalibr's "none"): taken
# without coefficients only, as coefficients under them follow no known model.
NO_DISTORTION_MODELS = ("", "none")
# Keys that name a camera's model, which must be a pinhole camera with OpenCV's distortion
# (_model_problem): ROS's and Kalibr's `distortion_model`, Kalibr's `camera_model` (its
# projection), and the 0 or 1 OpenCV's calibration sample writes as `fisheye_model`.
MODEL_KEYS = ("distortion_model", "camera_model", "fisheye_model")
# A number as JSON and YAML 1.2 write one (554, -0.2, 5.54e2, .5): read as a number from YAML's plain text,
# and named as what to write without quotes when a camera file gives it as text ("554").
DECIMAL_NUMBER = re.compile(r"^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?$")
# A camera of a Kalibr camchain: cam0, cam1, ...
KALIBR_CAMERA = re.compile(r"cam\d+")
# ROS's CameraInfo.roi: the part of the sensor read out, in px of the full, unbinned sensor (its
# do_rectify, whether consumers should rectify it, does not change what the raw image is).
ROI_KEYS = ("x_offset", "y_offset", "width", "height")
# How a camera whose images are a crop of its sensor is given: its principal point is where the crop
# puts it, which no calibration of the crop's own size has.
CROP_ADVICE = ("for a crop of a larger sensor, give the sensor's camera matrix, width and height, with the crop as roi "
               "(x_offset, y_offset, width, height, in the sensor's px)")
# The most numbers each value may hold: the 3x3 camera matrix, OpenCV's longest distortion vector
# (k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4 tx ty), Kalibr's intrinsics and resolution. Counted before they
# are read: a million numbers (a 4 MB PUT /api/camera) took 0.6 s to refuse.
MOST_MATRIX_VALUES, MOST_DISTORTION_VALUES, MOST_INTRINSICS_VALUES, MOST_RESOLUTION_VALUES = 9, 14, 4, 2
# Camera files nest their values a few levels deep (a ROS message's header.stamp.sec, a row of a Kalibr
# camera's 4x4 transform). Deeper, a file is no camera's, and reading it recursed past Python's stack
# (a RecursionError: a traceback, an HTTP 500) or, 20,000 to 40,000 levels down in OpenCV's
# FileStorage parser, past the process's (a segmentation fault: the server gone).
MAX_NESTING = 20
# OpenCV's calibration sample writes every view's corners too, some tens of kB, and `ros2 topic echo`
# a message of about 1 kB a frame until stopped; a camera file is under MAX_CAMERA_FILE_BYTES. A ROS,
# Kalibr or JSON camera has some tens of values (MAX_YAML_NODES): PyYAML reads about 25,000 a second
# (a list of a million numbers, 5 MB, took 38 s and 830 MB), so it stops at MAX_YAML_NODES.
MAX_CAMERA_FILE_BYTES, MAX_YAML_NODES = 1_000_000, 10_000


class CameraError(ValueError):
    """A camera file or intrinsics that cannot be used; the message says which and why."""


class GuardedYamlLoader(yaml.SafeLoader):
    """PyYAML's safe loader for the small files users write (camera files, sign maps), refusing with an
    `error` saying where: aliases (`*name`, and so `<<: *name` merges), as such a file has no use for them and they let a few hundred bytes stand for
    billions of values (a 421-byte file of nested aliases took 19 s and 3 GB to read); values nested
    more than MAX_NESTING deep, which PyYAML's recursion would take past Python's stack; more than
    MAX_YAML_NODES values; whole numbers too long for Python to read (a ValueError's traceback); and a
    key given twice in one mapping, of which PyYAML keeps the last without a word.
    Documents are composed one at a time: those after the first are not read. A subclass sets what
    the file is (`what`, `error`, `most_nodes` and `too_many`, the advice when it has more values)."""

    error: type[ValueError] = CameraError
    what = "camera file"
    most_nodes = MAX_YAML_NODES
    too_many = "a camera file has some tens: give one with the camera's matrix, distortion and image size"

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self.depth = self.nodes = 0

    def compose_node(self, parent: yaml.Node | None, index: object) -> yaml.Node:
        event = self.peek_event()
        mark = event.start_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}"
        if isinstance(event, yaml.AliasEvent):
            raise self.error(f"{where}: YAML alias *{event.anchor}: {self.what}s are read without anchors and "
                             "aliases; write the values out")
        if self.depth == MAX_NESTING:
            raise self.error(f"{where}: values nested more than {MAX_NESTING} levels deep, which no {self.what}'s are")
        self.nodes += 1
        if self.nodes > self.most_nodes:
            raise self.error(f"{where}: more than {self.most_nodes} values, where {self.too_many}")
        self.depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1

    def construct_yaml_int(self, node: yaml.ScalarNode) -> int:
        try:
            return super().construct_yaml_int(node)
        except ValueError:  # Python reads no whole number of more than sys.get_int_max_str_digits() digits
            mark = node.start_mark
            raise self.error(f"line {mark.line + 1}, column {mark.column + 1}: a whole number of {len(node.value)} "
                             f"characters, which no value in a {self.what} has") from None

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        """The mapping `node` as a dict; `error` saying where a key is given twice."""
        keys = set()
        # The keys as written, before flattening adds those of a `<<` merge, which the ones written override.
        for key_node, _ in node.value:
            # Other keys are merges, or lists and mappings, which PyYAML refuses as unhashable.
            if isinstance(key_node, yaml.ScalarNode) and key_node.tag != "tag:yaml.org,2002:merge":
                key = self.construct_object(key_node)
                if key in keys:
                    mark = key_node.start_mark
                    raise self.error(f"line {mark.line + 1}, column {mark.column + 1}: {key_given_twice(key)}")
                keys.add(key)
        return super().construct_mapping(node, deep)


GuardedYamlLoader.add_constructor("tag:yaml.org,2002:int", GuardedYamlLoader.construct_yaml_int)
# YAML 1.1 reads a number with an exponent but no dot or no sign in it (5.54e2, 1e3) as text, where JSON and
# YAML 1.2 read a number: it is one here too, so that text (a quoted "554") can be refused as no number.
GuardedYamlLoader.add_implicit_resolver("tag:yaml.org,2002:float", DECIMAL_NUMBER, list("-+0123456789."))
# Python's json writes non-finite floats as NaN and Infinity, and PUT /api/camera's JSON reads them so: read
# as those numbers here too (then refused as not finite), so that a JSON file says what that body says.
GuardedYamlLoader.add_implicit_resolver("tag:yaml.org,2002:float", re.compile(r"^(?:NaN|[-+]?Infinity)$"),
                                        list("N-+I"))


NESTED_TOO_DEEP = f"values nested more than {MAX_NESTING} levels deep, which no camera file's are"
# What OpenCV's FileStorage parsers recurse into: a flow bracket opening or closing, an XML element's
# start or end tag (group 1 "/" for an end tag, group 2 "/" for an empty element), and a line's run of
# compact block-sequence dashes (group 3: "- - - 1" nests three deep).
_FILESTORAGE_NESTING = re.compile(r"[\[{]|[\]}]|<(/?)[A-Za-z_][^<>]*?(/?)>|^[ \t]*((?:-[ \t]+)+)", re.MULTILINE)


@dataclass(frozen=True, eq=False)
class Camera:
    """Pinhole intrinsics for images of `width` x `height` px (both None: of a size not known, so never scaled).

    `source` says where the numbers came from ("file:<path>", "json", "assumed 60° hfov", ...).
    CameraError when the numbers are no real camera's (the bounds above MIN_FOV_DEG .. MAX_FOCAL_RATIO).
    Its principal point is held to a calibration's bounds where one comes in (principal_point_problem),
    not here: the cameras made from one (scaled to an image, of a shrunk copy) keep it where it is.
    `window`: where its images lie on the sensor its calibration is for, when they are part of it
    (`SensorWindow.camera`); None: the whole sensor, or not known.
    """

    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    width: int | None = None
    height: int | None = None
    source: str = "given"
    window: SensorWindow | None = None

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if v is not None and (not isinstance(v, (int, np.integer)) or not 0 < v <= MAX_IMAGE_SIDE_PX):
                raise CameraError(f"image {name} must be a positive whole number under 2**31 px; got {v!r}")
        if (self.width is None) != (self.height is None):
            given, missing = ("width", "height") if self.height is None else ("height", "width")
            raise CameraError(f"the image {given} is given without the image {missing}: give both, the size in px the "
                              "intrinsics are for (scaling them to other image sizes needs both), or neither")
        K = np.asarray(self.K, dtype=np.float64)
        if K.shape != (3, 3):
            raise CameraError(f"camera matrix must be 3x3; got shape {K.shape}")
        if not np.all(np.isfinite(K)):
            raise CameraError("camera matrix has non-finite values")
        if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
            raise CameraError("camera matrix must have the form [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
        problem = _focal_length_problem(K, self.width, self.height)
        if problem:
            raise CameraError(problem)
        # Sensor rows and columns are perpendicular to a fraction of a degree; |s| > fx is over 45° off.
        if abs(K[0, 1]) > K[0, 0]:
            raise CameraError(f"skew s={K[0, 1]:.6g} exceeds fx={K[0, 0]:.6g}; real cameras have s close to 0")
        dist = np.asarray(self.dist, dtype=np.float64).ravel()
        if dist.size not in (0, 4, 5, 8, 12, 14):
            raise CameraError(f"distortion must have 4, 5, 8, 12 or 14 coefficients; got {dist.size}")
        if not np.all(np.isfinite(dist)):
            raise CameraError("distortion coefficients must be finite")
        problem = _distortion_problem(K, dist, self.width, self.height)
        if problem:
            raise CameraError(problem)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist if dist.size else np.zeros(5))

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.dist != 0))

    @property
    def is_assumed(self) -> bool:
        return self.source.startswith("assumed")

    @property
    def is_exif(self) -> bool:
        """Intrinsics from a photo's EXIF focal length (`pipeline.exif`)."""
        return self.source.startswith("EXIF")

    def for_image(self, width: int, height: int) -> tuple[Camera, list[str]]:
        """Intrinsics for an image of `width` x `height` px, scaled when the calibration size differs.

        Returns the camera and warnings for people (empty when the size matches). CameraError when
        the image's aspect differs from the calibration's by more than MAX_ASPECT_CHANGE: a photo
        turned on its side, cropped or re-framed, whose intrinsics no scaling gives; and for a camera of
        part of a sensor (`window`) at any other size than its own.
        """
        if self.width is None or self.height is None:
            return self, self._check_unsized_fit(width, height)
        change = size_change((self.width, self.height), (width, height))
        if change == "same":
            return self, []
        if self.window is not None:
            raise CameraError(self.window.misfit(width, height))
        if change == "turned":  # a portrait phone photo
            raise CameraError(f"this {width}x{height} px image is the camera's {self.width}x{self.height} px turned "
                              "on its side: rotate the photo back, or calibrate the camera held this way")
        if change == "reframed":
            raise CameraError(f"this {width}x{height} px image has another aspect than the {self.width}x{self.height} "
                              "px the camera was calibrated at: a cropped or re-framed photo, whose intrinsics no "
                              f"scaling gives; calibrate the camera at {width}x{height}")
        sx, sy = width / self.width, height / self.height
        warnings = [f"image is {width}x{height} px but the camera was calibrated at {self.width}x{self.height}; "
                    f"intrinsics scaled by {sx:.5g} x {sy:.5g}"]
        K = resize_map(sx, sy) @ self.K
        try:
            return Camera(K, self.dist, width, height, self.source), warnings
        except CameraError as exc:
            raise CameraError(f"the camera calibrated at {self.width}x{self.height} px cannot be scaled to this "
                              f"{width}x{height} px image: {exc}") from None

    def _check_unsized_fit(self, width: int, height: int) -> list[str]:
        """Warnings why this camera without an image size may not be meant for a `width` x `height` px
        image; CameraError when it cannot be.

        Only now can its numbers be held against an image size. A principal point far from the
        centre but in the image is a warning, as such a file may be meant for any resolution; one
        outside the image, or focal lengths no camera has for it (in mm, say), are a CameraError, as
        a camera with an image size is: the pose would be meaningless (9 m off, for a phone's
        calibration at 4032x3024 on a 640x480 image).
        """
        problem = _focal_length_problem(self.K, width, height)
        if problem:
            raise CameraError(f"the camera has no image size and does not fit this {width}x{height} px image: "
                              f"{problem}")
        cx, cy = self.K[0, 2], self.K[1, 2]
        problem = _centre_problem(cx, cy, width, height)
        if problem is None:
            return []
        advice = _unsized_advice(cx, cy, width, height)
        # Pixel centres are at whole px, so an image spans -0.5 .. w - 0.5: a half pixel beyond, as a
        # file for twice the size puts it at w, on the corner.
        if not (-0.5 <= cx <= width + 0.5 and -0.5 <= cy <= height + 0.5):
            raise CameraError(f"the camera has no image size and its principal point ({cx:g}, {cy:g}) px lies outside "
                              f"this {width}x{height} px image, where a calibration puts it near the centre: {advice}")
        return [f"the camera has no image size and its {problem}: {advice}, or the pose is wrong"]

    def to_json(self) -> dict:
        """The intrinsics its images are taken with (px) and where they came from."""
        K = self.K
        return {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "dist": self.dist.tolist(),
                "width": self.width, "height": self.height, "source": self.source}

    def file_json(self) -> dict:
        """This camera as a camera file gives it, which camera_from_json reads back: a window of a sensor
        as the sensor's calibration with its roi and binning; any other as to_json."""
        if self.window is None:
            return self.to_json()
        return {**self.window.sensor.to_json(), "roi": dict(zip(ROI_KEYS, self.window.roi)),
                "binning_x": self.window.binning[0], "binning_y": self.window.binning[1], "source": self.source}


@dataclass(frozen=True, eq=False)
class SensorWindow:
    """The part of a sensor a camera's images are, as ROS's CameraInfo gives it (sensor_msgs/CameraInfo):
    `sensor`, the calibration of the whole sensor, full resolution and unbinned (K for its width x
    height px); `roi` (x_offset, y_offset, width, height) px of it read out, in its px; `binning`
    (x, y) sensor px summed into an image px across and down. Images are the roi's width // x by its
    height // y px."""

    sensor: Camera
    roi: tuple[int, int, int, int]
    binning: tuple[int, int]

    def camera(self) -> Camera:
        """The camera of the images read out: the sensor's K in their px, for their size.

        Sensor px (X, Y), pixel centres at whole numbers, is image px ((X - x_offset + 0.5) / bx - 0.5,
        (Y - y_offset + 0.5) / by - 0.5): image px u sums sensor px x_offset + bx·u .. + bx - 1, whose
        centre is there. ROS's image_geometry divides cx - x_offset by bx, a quarter of a pixel off at
        binning 2 (renders binned by averaging 2x2 and 3x3 px put the sign's corners where this puts
        them, 0.01 px on average, not there).
        """
        (x, y, w, h), (bx, by) = self.roi, self.binning
        to_image = np.array([[1 / bx, 0, (0.5 - x) / bx - 0.5], [0, 1 / by, (0.5 - y) / by - 0.5], [0, 0, 1]])
        return Camera(to_image @ self.sensor.K, self.sensor.dist, w // bx, h // by, self.sensor.source, self)

    def misfit(self, width: int, height: int) -> str:
        """Why an image of `width` x `height` px, another size than this window's images, cannot be taken
        with its camera, and what to do. Scaling it would be wrong: the whole sensor's image scaled to
        the window's intrinsics put the principal point thousands of px off, and the pose metres off."""
        (x, y, w, h), (bx, by) = self.roi, self.binning
        sensor = (self.sensor.width, self.sensor.height)
        given = ([f"roi {w}x{h} px at ({x}, {y})"] if (x, y, w, h) != (0, 0, *sensor) else []) + (
            [f"binning {bx}x{by}"] if (bx, by) != (1, 1) else [])
        keys = " and ".join(part.split()[0] for part in given)
        if size_change(sensor, (width, height)) in ("same", "scaled"):
            advice = f"for images of the whole sensor (at any resolution), leave the {keys} out of the file"
        else:
            advice = f"give it images as read out with that {keys}, or a camera file for {width}x{height} px images"
        verb = "make" if len(given) > 1 else "makes"
        return (f"this {width}x{height} px image is not the size of the images the camera file describes: its "
                f"{' and '.join(given)} of the {sensor[0]}x{sensor[1]} px sensor {verb} them {w // bx}x{h // by} px, "
                f"and its intrinsics are for that size only; {advice}")


def _field_of_view_deg(f: float, c: float, side: float | None) -> float:
    """Degrees a pinhole camera of focal length `f` (px) sees across an image `side` px long, about
    its centre (None: twice the principal point `c`, as a calibration puts it near the centre).
    About the principal point, a focal length and principal point both in mm (4.2 and 2.8) gave
    under 125° across 1280 px."""
    half = side / 2 if side is not None else c
    return math.degrees(2 * math.atan(half / f))


def principal_point_problem(camera: Camera) -> str | None:
    """Why `camera`'s principal point is no calibration's, or None: with an image size, more than
    MAX_CENTRE_OFFSET of a side off the image's centre (values in mm, or a file for another
    resolution, whose principal point is at a corner or a quarter in); without one, off the image
    whatever its size (negative) or beyond MAX_UNSIZED_PX. For what a calibration gives (a camera file,
    a chessboard fit), not for the cameras made from one: scaled, or of a crop of the image."""
    cx, cy = camera.K[0, 2], camera.K[1, 2]
    if camera.width is not None:
        return _centre_problem(cx, cy, camera.width, camera.height)
    # Pixel centres are at whole px, so an image spans -0.5 .. w - 0.5.
    if min(cx, cy) < -0.5:
        return (f"principal point ({cx:g}, {cy:g}) px is left of or above the image: it is in px from the image's "
                "top-left corner, near the image's centre")
    if max(cx, cy) > MAX_UNSIZED_PX:
        return (f"principal point ({cx:g}, {cy:g}) px is beyond {MAX_UNSIZED_PX:g} px, past any image; check the "
                "values, or give the file the image width and height")
    return None


def _unsized_advice(cx: float, cy: float, width: int, height: int) -> str:
    """What to give a camera file without an image size, whose principal point (cx, cy) px is far from
    the centre of a `width` x `height` px image: the image size it was made for, named when twice its
    principal point is this image's size scaled (a calibration puts it near its image's centre); else
    that, or the sensor this image is a crop of (the size of the crop alone would be refused)."""
    made_for = (round(2 * cx), round(2 * cy))
    if min(made_for) > 0 and size_change(made_for, (width, height)) == "scaled":
        return (f"the file was probably made for another resolution, {made_for[0]}x{made_for[1]} px (twice its principal "
                "point): give it that width and height, and it is scaled to this image")
    return ("the file was probably made for another resolution: give it that resolution's width and height, and it is "
            f"scaled to this image; {CROP_ADVICE}")


def _centre_problem(cx: float, cy: float, width: int, height: int) -> str | None:
    """Why principal point (cx, cy) px is no calibration's for a `width` x `height` px image (more
    than MAX_CENTRE_OFFSET of a side off its centre), or None."""
    if abs(cx - width / 2) > MAX_CENTRE_OFFSET * width or abs(cy - height / 2) > MAX_CENTRE_OFFSET * height:
        return (f"principal point ({cx:g}, {cy:g}) px is far from the centre ({width / 2:g}, {height / 2:g}) of "
                f"the {width}x{height} px image")
    return None


def _focal_length_problem(K: np.ndarray, width: int | None, height: int | None) -> str | None:
    """Why the focal lengths of camera matrix K (3, 3) px are no real camera's for an image of `width` x
    `height` px (None: not known): not positive, longer than MIN_FOV_DEG allows, shorter than MAX_FOV_DEG
    allows, or far from square; None if they are fine."""
    fx, fy = K[0, 0], K[1, 1]
    if fx <= 0 or fy <= 0:
        return f"focal lengths must be positive; got fx={fx}, fy={fy}"
    for axis, f, c, side in (("fx", fx, K[0, 2], width), ("fy", fy, K[1, 2], height)):
        if (fov := _field_of_view_deg(f, c, side)) > MAX_FOV_DEG:
            across = "across the image" if side is not None else "across twice its principal point"
            return (f"{axis}={f:.6g} px gives a field of view of {fov:.1f}° {across}, wider than a pinhole camera "
                    f"sees ({MAX_FOV_DEG:g}° at most): focal lengths are in pixels, not mm (fx = focal length in mm "
                    "x image width in px / sensor width in mm)")
    side = max((s for s in (width, height) if s is not None), default=None)
    longest = MAX_UNSIZED_PX if side is None else side / (2 * math.tan(math.radians(MIN_FOV_DEG) / 2))
    for axis, f in (("fx", fx), ("fy", fy)):
        if f <= longest:
            continue
        if side is None:
            return (f"{axis}={f:.6g} px is longer than {MAX_UNSIZED_PX:g} px, the most for a camera without an image "
                    "size; check the value, or give the file the image width and height")
        return (f"{axis}={f:.6g} px makes the image's {side} px a field of view under {MIN_FOV_DEG:g}°, narrower "
                "than any camera's; check that it is in pixels and for this image size")
    if not 1 / MAX_FOCAL_RATIO <= fx / fy <= MAX_FOCAL_RATIO:
        return (f"fx/fy = {fx / fy:.3g} (fx={fx:.6g}, fy={fy:.6g} px), but real pixels are near square; "
                "check both values")
    return None


def _distortion_problem(K: np.ndarray, dist: np.ndarray, width: int | None, height: int | None) -> str | None:
    """Why distortion `dist` is no real lens's for camera matrix K (3, 3) and a `width` x `height` px
    image (None: twice the principal point), or None: along the rays to the image corners, the
    distorted radius must stay within MAX_DISTORTION_FACTOR of the undistorted one."""
    if not np.any(dist):
        return None
    w, h = width or 2 * K[0, 2], height or 2 * K[1, 2]
    corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], np.float64)
    ends = np.column_stack([(corners[:, 0] - K[0, 2]) / K[0, 0], (corners[:, 1] - K[1, 2]) / K[1, 1]])
    rays = (np.linspace(0.1, 1.0, 10)[:, None, None] * ends).reshape(-1, 2)  # distorted radius ~ these
    rays = rays[np.hypot(rays[:, 0], rays[:, 1]) > 1e-9]
    if not len(rays):
        return None
    with np.errstate(all="ignore"):
        moved = cv2.projectPoints(np.column_stack([rays, np.ones(len(rays))]), np.zeros(3), np.zeros(3),
                                  np.eye(3), dist)[0].reshape(-1, 2)
        factor = np.hypot(moved[:, 0], moved[:, 1]) / np.hypot(rays[:, 0], rays[:, 1])
    worst = float(np.nanmax(np.abs(np.log(factor)))) if np.all(np.isfinite(factor)) and np.all(factor > 0) else math.inf
    if worst > math.log(MAX_DISTORTION_FACTOR):
        return (f"distortion {', '.join(f'{d:.6g}' for d in dist)} moves image points by more than "
                f"{MAX_DISTORTION_FACTOR:g}x their distance from the centre, which no real lens does; check the "
                "coefficients and their order (k1, k2, p1, p2, k3, ...)")
    return None


SizeChange = Literal["same", "scaled", "turned", "reframed"]


def size_change(calibrated: tuple[int, int], image: tuple[int, int]) -> SizeChange:
    """How an `image` size relates to the `calibrated` one (both (width, height) px): "same"; "scaled",
    the same aspect within MAX_ASPECT_CHANGE, whose intrinsics are the calibration's scaled; "turned",
    the frame on its side, maybe also resized; "reframed", cropped or another aspect. No scaling gives
    the intrinsics of the last two: they need a calibration of their own."""
    (cw, ch), (w, h) = calibrated, image
    if (cw, ch) == (w, h):
        return "same"
    aspect_change = abs((w / cw) / (h / ch) - 1)
    if abs((w / ch) / (h / cw) - 1) <= MAX_ASPECT_CHANGE < aspect_change:
        return "turned"
    return "reframed" if aspect_change > MAX_ASPECT_CHANGE else "scaled"


def check_hfov(hfov_deg: float) -> float:
    """`hfov_deg` as a float; CameraError unless it is a horizontal field of view in ASSUMED_HFOV_RANGE_DEG."""
    lo, hi = ASSUMED_HFOV_RANGE_DEG
    number = isinstance(hfov_deg, (int, float)) and not isinstance(hfov_deg, bool)
    if not number or not lo <= hfov_deg <= hi:
        # A number as typed (-0, 1e+03), not as Python writes floats: -0 was said as "got -0.0", or "0.0".
        given = f"{hfov_deg:g}" if number else reprlib.repr(hfov_deg)
        raise CameraError(f"the horizontal field of view must be {lo:g}° to {hi:g}°; got {given}")
    return float(hfov_deg)


def assumed_camera(width: int, height: int, hfov_deg: float = ASSUMED_HFOV_DEG, note: str | None = None,
                   sideways: bool = False) -> Camera:
    """A distortion-free camera for `width` x `height` px images, with square pixels, centred principal point
    and `hfov_deg` horizontal FOV: across the sensor's width, which is the image's height when it is shown
    `sideways` (a photo its EXIF orientation turns a quarter turn), so that however it was held the
    camera is the same.

    `note`, said in brackets after the field of view in `source` (and so wherever the assumption is
    reported): why nothing better was had, e.g. the EXIF focal length that was refused.
    """
    across, down = (height, width) if sideways else (width, height)
    f = (across / 2) / math.tan(math.radians(hfov_deg) / 2)
    # A strip far taller than wide (1 x 4000 px) would see more than a pinhole camera can down its
    # height, and the camera's own check refused it, blaming focal lengths in mm.
    tallest = MAX_FOV_DEG - 1
    if (down / 2) / f > math.tan(math.radians(tallest) / 2):
        f = (down / 2) / math.tan(math.radians(tallest) / 2)
        side = "wide" if sideways else "tall"
        note = ", ".join(filter(None, (note, f"narrower, as the image is {tallest:g}° {side}")))
    if sideways:
        note = ", ".join(filter(None, ("across the photo's height, the sensor's width, as its EXIF orientation shows "
                                       "it on its side", note)))
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
    source = f"assumed {hfov_deg:g}° horizontal field of view" + (f" ({note})" if note else "")
    return Camera(K, np.zeros(5), width, height, source)


def camera_from_json(data: dict, source: str = "json") -> Camera:
    """Camera from a parsed camera file or request: `{fx, fy, cx, cy, dist?, width?, height?}` (pixels),
    or any of the keys `load_camera` reads."""
    if not isinstance(data, dict):
        raise CameraError("camera JSON must be an object with fx, fy, cx, cy")
    return _camera_from_fields(data, source, "JSON")


def _number(value: object, name: str) -> float:
    """`value` as a float; CameraError naming the field `name` unless it is a number. Not text: a file's
    "554" is refused as PUT /api/camera's JSON is, and as docs/camera-files.md says."""
    if isinstance(value, Real) and not isinstance(value, bool):
        try:
            return float(value)
        except OverflowError:  # an integer past the float range
            pass
    raise _not_number_error(value, name, "a number")


def _not_number_error(value: object, name: str, what: str) -> CameraError:
    """The error for the value of `name`, which is not `what` ("a number", "a whole number"): a null
    and a number written as text (in quotes) are said to be."""
    if value is None:
        return CameraError(f"{name} is null: give it {what}")
    if isinstance(value, str) and DECIMAL_NUMBER.match(value.strip()):
        return CameraError(f"{name} must be {what}, not text: write {value.strip()} without quotes")
    # true and false as JSON and YAML write them, not as Python does
    shown = str(value).lower() if isinstance(value, bool) else reprlib.repr(value)
    return CameraError(f"{name} must be {what}; got {shown}")


def _numbers(value: object, name: str, most: int) -> np.ndarray:
    """A number, a list of numbers or a list of rows of numbers (a matrix), at most `most` of them, as a
    float64 array of its shape; CameraError naming `name` otherwise."""
    _check_count(value, name, most)
    items = np.array(value, dtype=object)  # ragged lists stay lists here, and _number rejects them
    return np.array([_number(v, name) for v in items.flat], dtype=np.float64).reshape(items.shape)


def _check_count(value: object, name: str, most: int) -> None:
    """CameraError naming `name` unless `value` is a number, or a list of numbers or of rows of them (as
    lists or arrays), of at most `most` numbers. Walked without recursion, refusing a list as soon as
    its length alone passes `most`, so that a million numbers, or lists nested a thousand deep, are
    refused before anything is made of them."""
    count, stack = 0, [(value, 0)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, list):
            if depth == 2:
                raise CameraError(f"{name} must be numbers, or rows of numbers; got lists nested deeper")
            if count + len(item) > most:  # each item holds at least one number
                raise CameraError(f"{name} has more than {most} values")
            stack.extend((v, depth + 1) for v in item)
        elif (count := count + (item.size if isinstance(item, np.ndarray) else 1)) > most:
            raise CameraError(f"{name} has more than {most} values")


def _opt_int(value: object, name: str) -> int | None:
    """`value` (None: absent) as an int; CameraError naming `name` unless it is a whole number."""
    if value is None:
        return None
    whole = isinstance(value, Integral) or (isinstance(value, Real) and float(value).is_integer())
    if isinstance(value, bool) or not whole:
        raise _not_number_error(value, name, "a whole number")
    return int(value)  # type: ignore[call-overload]  # a Real, which `whole` checked and mypy cannot narrow to


def _matrix(node: object, name: str, rows: int | None, cols: int | None, most: int) -> np.ndarray:
    """A ROS-style {rows, cols, data} node (or a plain nested list) named `name`, of at most `most`
    values, as an array."""
    if isinstance(node, dict) and "data" in node:
        data = _numbers(node["data"], f"{name}.data", most)
        r, c = _opt_int(node.get("rows", rows), f"{name}.rows"), _opt_int(node.get("cols", cols), f"{name}.cols")
        if r is not None and c is not None:
            if data.size != r * c:
                raise CameraError(f"{name} declares {r}x{c} but has {data.size} values")
            data = data.reshape(r, c)
        return data
    return _numbers(node, name, most)


def _one_of(fields: dict, keys: tuple[str, ...], what: str) -> tuple[str, object] | None:
    """(key, value) of the one of `keys` that `fields` gives (a null value is not given), None when it
    gives none; CameraError naming `what` when it gives several, as which one it means is unknown."""
    given = [k for k in keys if fields.get(k) is not None]
    if len(given) > 1:
        raise CameraError(f"{what} is given twice, as {' and '.join(given)}: keep the one meant")
    return (given[0], fields[given[0]]) if given else None


def _null_key(fields: dict, keys: tuple[str, ...]) -> str | None:
    """The first of `keys` that `fields` give as null, None when none is: a value lost on the way, which
    _one_of takes as not given, and whose error must say it is there but null."""
    return next((k for k in keys if k in fields and fields[k] is None), None)


def _refuse_unknown_distortion(fields: dict) -> None:
    """CameraError when `fields` has a key that looks like distortion (DISTORTION_LIKE) but is not one read."""
    known = (*DISTORTION_KEYS, *MODEL_KEYS)
    unknown = [str(k) for k in fields if k not in known and DISTORTION_LIKE.search(str(k))]
    if unknown:
        raise CameraError(f"{', '.join(unknown)}: not a key signpose reads, and without it the lens would be taken "
                          "as distortion-free; give the coefficients as one list in OpenCV's order (k1, k2, p1, p2"
                          f"[, k3, ...]) under {', '.join(DISTORTION_KEYS)}, and the model as distortion_model")


def _model_problem(fields: dict, dist: np.ndarray) -> str | None:
    """Why the model `fields` name (MODEL_KEYS) is not a pinhole camera with OpenCV's distortion `dist`;
    None when it is, or none is named. Other models' coefficients mean something else, so a pose
    from them is wrong without a word."""
    for key in MODEL_KEYS:
        model = fields.get(key)
        if model is None:
            continue
        name = model.lower() if isinstance(model, str) else None
        if key == "fisheye_model":
            usable = name is None and model == 0  # 0 or false: not calibrated as a fisheye
        elif key == "camera_model":
            usable = name == "pinhole"  # not Kalibr's omni, ds or eucm
        else:
            # A model naming no distortion with no coefficients is a camera without distortion.
            usable = name in OPENCV_DISTORTION_MODELS or (name in NO_DISTORTION_MODELS and not dist.any())
        if not usable:
            return (f"{key} {reprlib.repr(model)} is not supported: signpose uses OpenCV's model "
                    f"({', '.join(OPENCV_DISTORTION_MODELS[:-1])} or {OPENCV_DISTORTION_MODELS[-1]}: k1 k2 p1 p2 k3 "
                    "...) on a pinhole camera; calibrate with `signpose calibrate`, or undistort the photos first "
                    "and give zero distortion")
        most = MODEL_COEFFICIENTS.get(name)
        if most is not None and dist.size > most and dist.size in COEFFICIENT_COUNTS:
            terms, other = COEFFICIENT_COUNTS[dist.size]
            fix = f": set {key} to {other}" if other else f", which ROS and Kalibr name no model for: leave {key} out"
            return (f"{key} {model} has {most} coefficients ({COEFFICIENT_COUNTS[most][0]}), but {dist.size} are "
                    f"given ({terms}){fix}, or give {most}")
    return None


def _camera_matrix(fields: dict, kind: str) -> np.ndarray:
    """The 3x3 camera matrix `fields` give (MATRIX_KEYS, Kalibr's intrinsics, or fx, fy, cx, cy);
    CameraError naming the key, or saying that this `kind` of file has none."""
    found = _one_of(fields, (*MATRIX_KEYS, "intrinsics", "fx"), "the camera matrix")
    null = _null_key(fields, (*MATRIX_KEYS, "intrinsics", "fx"))
    if found is None and null is not None:
        raise CameraError(f"{null} is null: give it {'a number' if null == 'fx' else 'the camera matrix'}, in px")
    if found is None:
        raise CameraError(f"expected camera_matrix (ROS camera_info file), k (ROS 2 camera_info message, as "
                          f"`ros2 topic echo --once` prints it), K, cameraMatrix, intrinsics (Kalibr) or fx, fy, cx, "
                          f"cy keys; this {kind} has none")
    key, value = found
    if key in MATRIX_KEYS:
        K = _matrix(value, key, 3, 3, MOST_MATRIX_VALUES)
        if K.size != 9:
            raise CameraError(f"{key} must have 9 values (the 3x3 matrix, row by row); got {K.size}")
        if not K.any():  # CameraInfo's convention for a camera nobody calibrated, whatever its model says
            raise CameraError(f"{key} is all zeros: this camera_info is of an uncalibrated camera; calibrate it "
                              "(`signpose calibrate`, or ROS's camera_calibration) and give that file")
        return K.reshape(3, 3)
    if key == "intrinsics":
        focal = _numbers(value, key, MOST_INTRINSICS_VALUES).ravel()
        if focal.size != 4:
            raise CameraError(f"intrinsics must be Kalibr's pinhole [fu, fv, pu, pv] (fx, fy, cx, cy in px); "
                              f"got {reprlib.repr(value)}")
    else:
        missing = [k for k in ("fy", "cx", "cy") if k not in fields]
        if missing:
            raise CameraError(f"the camera matrix is missing {', '.join(missing)}: fx, fy, cx and cy give it together")
        focal = np.array([_number(fields[k], k) for k in ("fx", "fy", "cx", "cy")])
    fx, fy, cx, cy = focal
    return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])


def _camera_from_fields(fields: dict, source: str, kind: str) -> Camera:
    """Camera from the top-level keys and values of a camera file of `kind` ("YAML/JSON file", ...),
    whichever format it is (see load_camera): the matrix, distortion, model and image size under
    the keys MATRIX_KEYS .. MODEL_KEYS. CameraError naming the key as the file writes it."""
    _refuse_unknown_distortion(fields)
    found = _one_of(fields, DISTORTION_KEYS, "the distortion")
    dist = np.zeros(0) if found is None else _matrix(found[1], found[0], None, None, MOST_DISTORTION_VALUES).ravel()
    model = fields.get("distortion_model")
    if not dist.size and isinstance(model, str) and model.lower() in OPENCV_DISTORTION_MODELS:
        # A lens calibrated with distortion whose coefficients were lost on the way (the key, or its
        # values): read as none, the pose moved 0.25 m at 1.7 m without a word.
        missing = f"({found[0]} is empty)" if found else f"(under {', '.join(DISTORTION_KEYS)})"
        raise CameraError(f"distortion_model {model} names a lens with distortion, but the file gives no "
                          f"coefficients {missing}: add them, or set distortion_model to none for a lens without "
                          "distortion")
    problem = _model_problem(fields, dist)
    if problem:
        raise CameraError(problem)
    camera = Camera(_camera_matrix(fields, kind), dist, *_image_size(fields), source)
    problem = principal_point_problem(camera)
    if problem and camera.width is not None:
        problem += (": a calibration puts it within a few percent of the centre; check that the values are in pixels "
                    "and that the file's image size is the calibration's" + ("" if fields.get("roi") is not None else
                                                                              f"; {CROP_ADVICE}"))
    if problem:
        raise CameraError(problem)
    window = _sensor_window(fields, camera)
    return camera if window is None else window.camera()


def _sensor_window(fields: dict, sensor: Camera) -> SensorWindow | None:
    """The part of `sensor` the images are that `fields` give (ROS's `roi` and `binning_x`, `binning_y`),
    None for the whole sensor unbinned (an all-zero or absent roi, binning 0 or 1); CameraError naming
    the key for a roi off the sensor, or a window without the sensor's size it is in px of."""
    roi = fields.get("roi")
    binning_x, binning_y = (_whole(fields.get(key), key) or 1 for key in ("binning_x", "binning_y"))  # ROS: 0 is 1
    binning = (binning_x, binning_y)

    if roi is not None:
        if not isinstance(roi, dict) or set(roi) - {"do_rectify"} != set(ROI_KEYS):
            raise CameraError(f"roi must be x_offset, y_offset, width and height, in px of the full, unbinned sensor "
                              f"(ROS's CameraInfo.roi); got {reprlib.repr(roi)}")
        null = next((key for key in ROI_KEYS if roi[key] is None), None)
        if null is not None:  # ROS's "all of the sensor" is all zeros; nulls are values lost on the way
            raise CameraError(f"roi.{null} is null: give the roi as whole numbers of px (all zeros for the whole "
                              "sensor), or leave the roi out")
        roi = tuple(_whole(roi[key], f"roi.{key}") for key in ROI_KEYS)
    if roi is None or not any(roi):  # ROS's all-zero roi is the whole sensor
        if binning == (1, 1):
            return None
        roi = (0, 0, sensor.width, sensor.height)
    if sensor.width is None:
        raise CameraError("roi and binning are in px of the full, unbinned sensor: give its image_width and "
                          "image_height (or width and height) too")
    x, y, w, h = roi
    if not (w and h):
        raise CameraError(f"roi width and height must be positive (an all-zero roi is the whole sensor); got {w}x{h}")
    if x + w > sensor.width or y + h > sensor.height:
        raise CameraError(f"roi {w}x{h} px at ({x}, {y}) reaches past the {sensor.width}x{sensor.height} px sensor: "
                          "the roi is in px of the full, unbinned sensor, and the camera matrix, width and height "
                          "are the whole sensor's")
    if w < binning[0] or h < binning[1]:
        raise CameraError(f"binning {binning[0]}x{binning[1]} leaves no image px of the {w}x{h} px roi")
    return SensorWindow(sensor, (x, y, w, h), binning)



def _whole(value: object, name: str) -> int | None:
    """`value` (None: absent) as a whole number of px, 0 to MAX_IMAGE_SIDE_PX; CameraError naming `name`."""
    number = _opt_int(value, name)
    if number is not None and not 0 <= number <= MAX_IMAGE_SIDE_PX:
        raise CameraError(f"{name} must be a whole number of px from 0 to 2**31 - 1; got {number}")
    return number


def _image_size(fields: dict) -> tuple[int | None, int | None]:
    """The image width and height in px that `fields` give (WIDTH_KEYS, HEIGHT_KEYS, or Kalibr's
    resolution [width, height]), None for one not given; CameraError naming the key."""
    width, height = (_one_of(fields, keys, f"the image {what}")
                     for keys, what in ((WIDTH_KEYS, "width"), (HEIGHT_KEYS, "height")))
    # Both null is no size (GET /api/camera/file writes a camera without one so); one alone is a size half lost.
    one_alone = (width is None) != (height is None)
    null = _null_key(fields, WIDTH_KEYS if width is None else HEIGHT_KEYS) if one_alone else None
    if null is not None:
        raise CameraError(f"{null} is null: give it a number, or leave out both the image width and height")
    resolution = fields.get("resolution")
    if resolution is None:
        given_width, given_height = (None if f is None else _opt_int(f[1], f[0]) for f in (width, height))
        return given_width, given_height

    if width or height:
        other = (width or height)[0]
        raise CameraError(f"the image size is given twice, as resolution and {other}: keep the one meant")
    values = _numbers(resolution, "resolution", MOST_RESOLUTION_VALUES).ravel()
    if values.size != 2:
        raise CameraError(f"resolution must be [width, height] in px; got {reprlib.repr(resolution)}")
    return _opt_int(float(values[0]), "resolution width"), _opt_int(float(values[1]), "resolution height")


def _kalibr_camera(data: dict) -> tuple[str, dict] | None:
    """The name and fields of the camera of a Kalibr camchain (`cam0: {camera_model, intrinsics,
    distortion_model, distortion_coeffs, resolution, ...}`), None when `data` is none.

    A camchain of several cameras (a stereo rig's cam0, cam1) is refused, asking which: the file
    cannot say which camera took the photos, and taking cam0 would give the other's photos poses
    off without a word. One camera is taken under any name (a copy of the file keeping cam1 alone).
    """
    names = [k for k, v in data.items() if isinstance(k, str) and KALIBR_CAMERA.fullmatch(k) and isinstance(v, dict)]
    if len(names) > 1:
        raise CameraError(f"this Kalibr camchain has {len(names)} cameras ({', '.join(names)}) and signpose needs the "
                          "one that took the photos: give a copy of the file with only that camera's block")
    return (names[0], data[names[0]]) if names else None


def _filestorage_value(node: cv2.FileNode, depth: int = 1) -> object:
    """A FileStorage node `depth` levels down as Python: a number, text, a list, an array for an OpenCV
    matrix, else a dict; CameraError for a node more than MAX_NESTING levels down."""
    if depth > MAX_NESTING:
        raise CameraError(NESTED_TOO_DEEP)
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return node.real()
    if node.isString():
        return node.string()
    if node.isSeq():
        return [_filestorage_value(node.at(i), depth + 1) for i in range(node.size())]
    if node.isMap():
        keys = _filestorage_keys(node)  # an OpenCV matrix's too: its rows or data given twice
        try:
            return node.mat()
        except cv2.error:  # a mapping that is no matrix, or a matrix with data that are not numbers: its
            # fields, which _matrix reads as ROS's {rows, cols, data} and names what is wrong in them
            return {k: _filestorage_value(node.getNode(k), depth + 1) for k in keys}
    return None


def _filestorage_keys(node: cv2.FileNode) -> tuple[str, ...]:
    """The keys of the FileStorage mapping `node`; CameraError for a key given twice, of which OpenCV reads
    the first without a word."""
    keys = node.keys()
    twice = next((key for key, count in Counter(keys).items() if count > 1), None)
    if twice is not None:
        raise CameraError(key_given_twice(twice))
    return keys


def _xml_declaration_first(text: str) -> str:
    """XML `text` starting with its `<?xml ...?>` declaration, as OpenCV tells XML by it: added when
    missing (hand-made files leave it out), and put before blank lines that preceded it. Those lines
    go after it, so that OpenCV's line numbers stay the file's."""
    body = text.lstrip()
    end = body.find("?>") + 2 if body.startswith("<?xml") else 0
    if end == 1:  # a declaration without its end: OpenCV says what is wrong
        return text
    return (body[:end] or '<?xml version="1.0"?>') + text[:len(text) - len(body)] + body[end:]


def _filestorage_too_deep(text: str) -> bool:
    """Whether OpenCV's FileStorage parser might recurse more than MAX_NESTING levels into `text`: the
    flow brackets and XML elements open, plus a line's compact dashes (_FILESTORAGE_NESTING). A bound,
    not a parse: brackets in quoted text count too. Nesting by indentation is not counted: in a
    camera file's MAX_CAMERA_FILE_BYTES it reaches under 1,500 levels, which OpenCV takes."""
    depth = 0
    for token in _FILESTORAGE_NESTING.finditer(text):
        if token[3]:
            deepest = depth + token[3].count("-")
        else:
            depth += -1 if token[0] in "]}" or token[1] else 0 if token[2] else 1
            deepest = depth
        if deepest > MAX_NESTING:
            return True
    return False


def _filestorage_fields(text: str, syntax: str) -> dict:
    """The top-level nodes of the OpenCV FileStorage `text` in `syntax` (_filestorage_syntax), as
    Python (_filestorage_value). CameraError for values nested more than MAX_NESTING deep, before
    OpenCV's parser, whose recursion a deep enough file takes past the process's stack."""
    if _filestorage_too_deep(text):
        raise CameraError(NESTED_TOO_DEEP)
    if syntax == "XML":
        text = _xml_declaration_first(text)
    try:
        # From the text, not the file: OpenCV reads a file's byte-order mark as YAML, and fails.
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except SystemError as exc:  # OpenCV 5's binding wraps the cv2.error of a file it cannot parse
        if not isinstance(exc.__cause__, cv2.error):
            raise
        raise exc.__cause__ from None
    try:
        root = fs.root()
        return {k: _filestorage_value(root.getNode(k)) for k in _filestorage_keys(root)}
    finally:
        fs.release()


def load_camera(path: str | Path) -> Camera:
    """Read a camera file: a ROS camera_info YAML (the calibration file, or the message as `ros2 topic
    echo` prints it), an OpenCV FileStorage YAML, XML or JSON, a Kalibr camchain of one camera
    (_kalibr_camera), or JSON `{fx, fy, cx, cy, dist}`.

    Every format is read with the same keys (MATRIX_KEYS, DISTORTION_KEYS, WIDTH_KEYS, HEIGHT_KEYS,
    MODEL_KEYS, and ROS's `roi`, `binning_x`, `binning_y`: _sensor_window), so that e.g. `dist_coeffs`
    beside a `camera_matrix` list is read, not dropped. Other keys (a calibration's date, error and
    board; a message's header, `r` and `p`, as the rectification and projection matrices are not
    used) are ignored, except those that look like distortion or a lens model (DISTORTION_LIKE), which
    are refused. Files that no camera file is (nested deep, large, YAML aliases) are refused before
    they are read far: see GuardedYamlLoader and _filestorage_fields. OpenCV's distortion model
    only (ROS's `plumb_bob` or `rational_polynomial`, Kalibr's pinhole `radtan`; the calibration
    sample's `fisheye_model: 0`): any other is refused, since its coefficients mean something else.
    A file that names no model cannot be told from OpenCV's: cv2.fisheye's 4 coefficients without
    one are read as k1 k2 p1 p2. Errors name the key as the file writes it.
    """
    path = Path(path)
    try:
        with path.open("rb") as file:
            data = file.read(MAX_CAMERA_FILE_BYTES + 1)
    except FileNotFoundError:
        raise CameraError(f"camera file not found: {path}") from None
    return read_camera(data, str(path))


def read_camera(data: bytes, name: str, source: str | None = None) -> Camera:
    """The camera file `name` from its bytes `data`, read as `load_camera` reads a file (which sees
    only the text, whatever `name`'s suffix): for a file that is not on disk, such as an upload.
    `source` says where it came from (Camera.source), by default "file:<name>"; CameraError messages
    name `name`."""
    if len(data) > MAX_CAMERA_FILE_BYTES:
        raise CameraError(f"camera file {name} is over {MAX_CAMERA_FILE_BYTES // 1000} kB, which no camera file "
                          "is: give one with the camera's matrix, distortion and image size")
    try:
        text = _camera_text(data)
    except ValueError:  # a UnicodeDecodeError, or a NUL character
        raise CameraError(f"camera file {name} is not text (UTF-8, or UTF-16 with a byte-order mark)") from None
    try:
        return _parse_camera(text, f"file:{name}" if source is None else source)
    except CameraError as exc:
        raise CameraError(f"{name}: {exc}") from None


def _camera_text(data: bytes) -> str:
    """The text of a camera file's bytes `data`: UTF-8, without the byte-order mark Windows editors
    write, or UTF-16 with its mark (what Windows PowerShell 5's `>` writes). UnicodeDecodeError, or
    ValueError for a NUL character, which no text has and OpenCV would read as the end of the file."""
    text = data.decode("utf-16" if data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)) else "utf-8-sig")
    if "\0" in text:
        raise ValueError("a NUL character")
    return text


def _filestorage_syntax(text: str) -> str | None:
    """The syntax of `text` when it is an OpenCV FileStorage file, None when it is plain YAML or JSON:
    "XML" for any XML (OpenCV's calibration sample writes it by default), else "YAML" or "JSON" for
    text with OpenCV's `%YAML` directive or matrix type."""
    start = text.lstrip()
    if start.startswith("<"):
        return "XML"
    if start.startswith("%YAML") or "!!opencv-matrix" in text:
        return "YAML"
    if '"type_id": "opencv-matrix"' in text:
        return "JSON" if start.startswith("{") else "YAML"
    return None


def _parse_camera(text: str, source: str) -> Camera:
    """Camera from the `text` of a camera file, `source` its Camera.source; CameraError messages leave
    the file's name to the caller."""
    if not text.strip():
        raise CameraError(EMPTY_FILE)
    syntax = _filestorage_syntax(text)
    if syntax:
        try:
            fields = _filestorage_fields(text, syntax)
        except cv2.error as exc:
            raise CameraError(f"not a readable OpenCV FileStorage {syntax} file ({_opencv_error(exc)})") from None
        return _camera_from_fields(fields, source, f"OpenCV FileStorage {syntax} file")
    try:
        # YAML is a superset of JSON. `ros2 topic echo` ends each message with "---", which starts
        # another (empty) document; without --once it prints one after the other: the first is used.
        data = next((d for d in yaml.load_all(text, GuardedYamlLoader) if d is not None), None)
    except yaml.YAMLError as exc:
        raise CameraError(f"neither valid YAML nor JSON ({_yaml_error(exc)})") from None
    if not isinstance(data, dict):
        raise CameraError("expected a mapping with camera_matrix or k (ROS camera_info) or fx, fy, cx, cy")
    kalibr = _kalibr_camera(data)
    if kalibr is None:
        return _camera_from_fields(data, source, "YAML/JSON file")
    name, fields = kalibr
    try:
        return _camera_from_fields(fields, source, "Kalibr camera")
    except CameraError as exc:  # the key is the camera's, as in the file
        raise CameraError(f"{name}: {exc}") from None


def _yaml_error(exc: yaml.YAMLError) -> str:
    """The YAML parser's multi-line message (problem, quoted source, caret) as one line that keeps
    the problem and where it is (1-based line and column), and the construct it was in."""
    mark, problem = getattr(exc, "problem_mark", None), getattr(exc, "problem", None)
    if mark is None or problem is None:  # a ReaderError (a control character) has a character offset
        where = f"character {exc.position + 1}: " if isinstance(exc, yaml.reader.ReaderError) else ""
        return where + str(exc).splitlines()[0]
    message = f"line {mark.line + 1}, column {mark.column + 1}: {problem}"
    context, start = getattr(exc, "context", None), getattr(exc, "context_mark", None)
    if context and start:
        message += f", {context} that starts at line {start.line + 1}, column {start.column + 1}"
    return message


def _opencv_error(exc: cv2.error) -> str:
    """OpenCV's message without its source file and function: for a parse error, the line and reason."""
    if exc.code == cv2.Error.StsParseError:
        # Its "function" is "<path>(<line>): <reason>", where the path is empty, or for some errors
        # the text read: the last "(<line>): " is the one OpenCV added.
        parse = re.search(r".*\((\d+)\): (.*)$", exc.func or "", re.DOTALL)
        if parse:
            return f"line {parse[1]}: {parse[2]}"
    return (exc.err or str(exc)).strip().splitlines()[-1]


def ros_camera_yaml(camera: Camera, name: str = "camera") -> str:
    """ROS camera_info YAML text for `camera` (plumb_bob for 5 coefficients)."""
    d = camera.dist.tolist()
    P = np.hstack([camera.K, np.zeros((3, 1))])
    doc = {
        "image_width": camera.width, "image_height": camera.height, "camera_name": name,
        "camera_matrix": {"rows": 3, "cols": 3, "data": camera.K.ravel().tolist()},
        "distortion_model": "plumb_bob" if len(d) == 5 else "rational_polynomial",
        "distortion_coefficients": {"rows": 1, "cols": len(d), "data": d},
        "rectification_matrix": {"rows": 3, "cols": 3, "data": np.eye(3).ravel().tolist()},
        "projection_matrix": {"rows": 3, "cols": 4, "data": P.ravel().tolist()},
    }
    return yaml.safe_dump(doc, sort_keys=False)


def save_camera(camera: Camera, path: str | Path, name: str = "camera") -> None:
    Path(path).write_text(ros_camera_yaml(camera, name), encoding="utf-8")
