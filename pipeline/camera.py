"""Camera intrinsics: loading ROS (file or message) / OpenCV / plain-JSON camera files, and an assumed camera.

K is the OpenCV 3x3 matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels; `dist` is OpenCV's
(k1, k2, p1, p2[, k3, ...]) distortion vector.
"""

from __future__ import annotations

import math
import re
import reprlib
from dataclasses import dataclass, field
from numbers import Integral, Real
from pathlib import Path

import cv2
import numpy as np
import yaml

from .jsonfile import EMPTY_FILE

ASSUMED_HFOV_DEG = 60.0
# Fields of view one may assume: rectilinear lenses from a long telephoto to an ultra-wide.
ASSUMED_HFOV_RANGE_DEG = (10.0, 140.0)

# Bounds no real camera violates, so that a typo, a unit mix-up or a file for another camera is
# refused where it is loaded rather than giving nonsense poses (or, far out, at fx = 1e100..1e300 px,
# a reprojection error of 1e100 px, LAPACK chatter on stdout, and an SVD that does not converge).
# A field of view under 0.1° is a telescope's: even the longest zoom a UAV carries sees several times
# wider. It is held against the image's longer side, as a crop to a thin strip is still a camera.
MIN_FOV_DEG = 0.1
# Without an image size, focal lengths and the principal point can only be held against a number:
# 1e6 px is 0.1° across 1745 px, and far beyond any sensor (the widest aerial cameras have under
# 30 000 px). A file for a longer lens gives its image size; for_image checks again against the image.
MAX_UNSIZED_PX = 1e6
# A calibrated principal point lies within a few percent of the image centre (lens decentring); a
# quarter of the width or height off means a file for another resolution (one for twice the size
# puts it on this image's corner, half the width and height off).
MAX_CENTRE_OFFSET = 0.25
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
# ROS camera_info's names for OpenCV's distortion model with 5 and with 8 coefficients.
ROS_DISTORTION_MODELS = ("plumb_bob", "rational_polynomial")


class CameraError(ValueError):
    """A camera file or intrinsics that cannot be used; the message says which and why."""


@dataclass(frozen=True, eq=False)
class Camera:
    """Pinhole intrinsics for images of `width` x `height` px (both None: of a size not known, so never scaled).

    `source` says where the numbers came from ("file:<path>", "json", "assumed 60° hfov", ...).
    CameraError when the numbers are no real camera's (the bounds above MIN_FOV_DEG .. MAX_FOCAL_RATIO).
    """

    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    width: int | None = None
    height: int | None = None
    source: str = "given"

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
        problem = _focal_length_problem(K[0, 0], K[1, 1], self.width, self.height)
        if problem:
            raise CameraError(problem)
        # Sensor rows and columns are perpendicular to a fraction of a degree; |s| > fx is over 45° off.
        if abs(K[0, 1]) > K[0, 0]:
            raise CameraError(f"skew s={K[0, 1]:.6g} exceeds fx={K[0, 0]:.6g}; real cameras have s close to 0")
        cx, cy = K[0, 2], K[1, 2]
        w, h = self.width or MAX_UNSIZED_PX, self.height or MAX_UNSIZED_PX
        if not (0 <= cx <= w and 0 <= cy <= h):
            raise CameraError(f"principal point ({cx:.6g}, {cy:.6g}) px lies outside the image (0..{w:g} x 0..{h:g} px)")
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
        turned on its side, cropped or re-framed, whose intrinsics no scaling gives.
        """
        if self.width is None or self.height is None:
            return self, self._unsized_warnings(width, height)
        if (self.width, self.height) == (width, height):
            return self, []
        sx, sy = width / self.width, height / self.height
        if abs((width / self.height) / (height / self.width) - 1) <= MAX_ASPECT_CHANGE < abs(sx / sy - 1):
            # the camera's frame turned on its side, maybe also resized: a portrait phone photo
            raise CameraError(f"this {width}x{height} px image is the camera's {self.width}x{self.height} px turned "
                              "on its side: rotate the photo back, or calibrate the camera held this way")
        if abs(sx / sy - 1) > MAX_ASPECT_CHANGE:
            raise CameraError(f"this {width}x{height} px image has another aspect than the {self.width}x{self.height} "
                              "px the camera was calibrated at: a cropped or re-framed photo, whose intrinsics no "
                              f"scaling gives; calibrate the camera at {width}x{height}")
        warnings = [f"image is {width}x{height} px but the camera was calibrated at {self.width}x{self.height}; "
                    f"intrinsics scaled by {sx:.5g} x {sy:.5g}"]
        K = np.diag([sx, sy, 1.0]) @ self.K
        try:
            return Camera(K, self.dist, width, height, self.source), warnings
        except CameraError as exc:
            raise CameraError(f"the camera calibrated at {self.width}x{self.height} px cannot be scaled to this "
                              f"{width}x{height} px image: {exc}") from None

    def _unsized_warnings(self, width: int, height: int) -> list[str]:
        """Why this camera without an image size may not be meant for a `width` x `height` px image.

        Only now can its numbers be held against an image size. Warnings, not errors: such a file
        may be meant for any resolution, and MAX_UNSIZED_PX already keeps the arithmetic sound.
        """
        warnings = []
        problem = _focal_length_problem(self.K[0, 0], self.K[1, 1], width, height)
        if problem:
            warnings.append(f"the camera has no image size and does not fit this {width}x{height} px image: "
                            f"{problem}; the pose is meaningless")
        cx, cy = self.K[0, 2], self.K[1, 2]
        if abs(cx - width / 2) > MAX_CENTRE_OFFSET * width or abs(cy - height / 2) > MAX_CENTRE_OFFSET * height:
            warnings.append(f"the camera has no image size and its principal point ({cx:g}, {cy:g}) px is far from "
                            f"the centre ({width / 2:g}, {height / 2:g}) of this {width}x{height} px image: the file "
                            "was probably made for another resolution; give it that resolution's width and height "
                            "so it is scaled to the image, or the pose is wrong")
        return warnings

    def to_json(self) -> dict:
        K = self.K
        return {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "dist": self.dist.tolist(),
                "width": self.width, "height": self.height, "source": self.source}


def _focal_length_problem(fx: float, fy: float, width: int | None, height: int | None) -> str | None:
    """Why focal lengths `fx`, `fy` (px) are no real camera's for an image of `width` x `height` px
    (None: not known): not positive, longer than MIN_FOV_DEG allows, or far from square; None if they are fine."""
    if fx <= 0 or fy <= 0:
        return f"focal lengths must be positive; got fx={fx}, fy={fy}"
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


def check_hfov(hfov_deg: float) -> float:
    """`hfov_deg` as a float; CameraError unless it is a horizontal field of view in ASSUMED_HFOV_RANGE_DEG."""
    lo, hi = ASSUMED_HFOV_RANGE_DEG
    if isinstance(hfov_deg, bool) or not isinstance(hfov_deg, (int, float)) or not lo <= hfov_deg <= hi:
        raise CameraError(f"the horizontal field of view must be {lo:g}° to {hi:g}°; got {hfov_deg!r}")
    return float(hfov_deg)


def assumed_camera(width: int, height: int, hfov_deg: float = ASSUMED_HFOV_DEG, note: str | None = None) -> Camera:
    """A distortion-free camera with square pixels, centred principal point and `hfov_deg` horizontal FOV.

    `note`, said in brackets after the field of view in `source` (and so wherever the assumption is
    reported): why nothing better was had, e.g. the EXIF focal length that was refused.
    """
    f = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
    source = f"assumed {hfov_deg:g}° horizontal field of view" + (f" ({note})" if note else "")
    return Camera(K, np.zeros(5), width, height, source)


def camera_from_json(data: dict, source: str = "json") -> Camera:
    """Camera from `{fx, fy, cx, cy, dist?, width?, height?}` (pixels)."""
    if not isinstance(data, dict):
        raise CameraError("camera JSON must be an object with fx, fy, cx, cy")
    missing = [k for k in ("fx", "fy", "cx", "cy") if k not in data]
    if missing:
        raise CameraError(f"camera JSON is missing {', '.join(missing)}")
    fx, fy, cx, cy = (_number(data[k], k) for k in ("fx", "fy", "cx", "cy"))
    dist = _numbers(data.get("dist") or [], "dist")
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    return Camera(K, dist, _opt_int(data.get("width"), "width"), _opt_int(data.get("height"), "height"), source)


def _number(value: object, name: str) -> float:
    """`value` as a float; CameraError naming the field `name` unless it is a number.

    Numeric text counts: YAML 1.1 reads an exponent without a dot and sign (`1e3`) as a string.
    """
    if isinstance(value, (str, Real)) and not isinstance(value, bool):
        try:
            return float(value)
        except (ValueError, OverflowError):  # text that is no number; an integer past the float range
            pass
    raise CameraError(f"{name} must be a number; got {reprlib.repr(value)}")


def _numbers(value: object, name: str) -> np.ndarray:
    """A number or (nested) list of numbers as a float64 array of its shape; CameraError naming `name` otherwise."""
    items = np.array(value, dtype=object)  # ragged lists stay lists here, and _number rejects them
    return np.array([_number(v, name) for v in items.flat], dtype=np.float64).reshape(items.shape)


def _opt_int(value: object, name: str) -> int | None:
    """`value` (None: absent) as an int; CameraError naming `name` unless it is a whole number."""
    if value is None:
        return None
    whole = isinstance(value, Integral) or (isinstance(value, Real) and float(value).is_integer())
    if isinstance(value, bool) or not whole:
        raise CameraError(f"{name} must be a whole number; got {reprlib.repr(value)}")
    return int(value)


def _matrix(node: object, name: str, rows: int | None, cols: int | None) -> np.ndarray:
    """A ROS-style {rows, cols, data} node (or a plain nested list) named `name` as an array."""
    if isinstance(node, dict) and "data" in node:
        data = _numbers(node["data"], f"{name}.data")
        r, c = _opt_int(node.get("rows", rows), f"{name}.rows"), _opt_int(node.get("cols", cols), f"{name}.cols")
        if r is not None and c is not None:
            if data.size != r * c:
                raise CameraError(f"{name} declares {r}x{c} but has {data.size} values")
            data = data.reshape(r, c)
        return data
    return _numbers(node, name)


def is_ros_message(data: dict) -> bool:
    """Whether parsed YAML is a sensor_msgs/CameraInfo message as `ros2 topic echo` prints it (`k`, `d`,
    `width`, `height`, flat lists) or ROS 1's `rostopic echo` (`K`, `D`), rather than the file ROS's
    camera_calibration writes (`camera_matrix: {rows, cols, data}`, `image_width`, ...)."""
    return "camera_matrix" not in data and ("k" in data or "K" in data)


def camera_from_ros(data: dict, source: str) -> Camera:
    """Camera from a parsed ROS camera_info: the calibration file (`camera_matrix`, `distortion_coefficients`,
    `image_width`, `image_height`) or the message (`is_ros_message`: `k`, 9 numbers row by row, `d`,
    `width`, `height`; `header`, `r`, `p`, binning and roi are not used, as the file's rectification and
    projection matrices are not). OpenCV's distortion model only (ROS's `plumb_bob` or
    `rational_polynomial`); any other `distortion_model` is refused, since its coefficients mean
    something else. Errors name the key as the file writes it."""
    if is_ros_message(data):
        matrix, distortion = ("k", "d") if "k" in data else ("K", "D")
        width, height = "width", "height"
    else:
        matrix, distortion, width, height = "camera_matrix", "distortion_coefficients", "image_width", "image_height"
    K = _matrix(data[matrix], matrix, 3, 3)
    if K.size != 9:
        raise CameraError(f"{matrix} must have 9 values (the 3x3 matrix, row by row); got {K.size}")
    if not K.any():  # CameraInfo's convention for a camera nobody calibrated, whatever its model says
        raise CameraError(f"{matrix} is all zeros: this camera_info is of an uncalibrated camera; calibrate it "
                          "(`signpose calibrate`, or ROS's camera_calibration) and give that file")
    dist = _matrix(data.get(distortion, {"data": []}), distortion, None, None)
    model = data.get("distortion_model")
    # An empty model (the field never set) with no coefficients is a camera without distortion.
    if model not in (None, *ROS_DISTORTION_MODELS) and not (model == "" and not dist.any()):
        raise CameraError(f"distortion_model {reprlib.repr(model)} is not supported: signpose uses OpenCV's model "
                          f"({' or '.join(ROS_DISTORTION_MODELS)}: k1 k2 p1 p2 k3 ...); calibrate with "
                          "`signpose calibrate`, or undistort the photos first and give zero distortion")
    return Camera(K.reshape(3, 3), dist.ravel(), _opt_int(data.get(width), width), _opt_int(data.get(height), height),
                  source)


def _filestorage_matrix(fs: cv2.FileStorage, names: tuple[str, ...]) -> np.ndarray | None:
    """The first of the nodes `names` that `fs` has, as an array; None when it has none of them."""
    name = next((n for n in names if not fs.getNode(n).empty()), None)
    if name is None:
        return None
    try:
        return fs.getNode(name).mat()
    except cv2.error:  # a scalar, a plain list, a mapping that is no matrix, or non-numeric data
        raise CameraError(f"{name} is not an OpenCV matrix of numbers") from None


def _filestorage_int(fs: cv2.FileStorage, name: str) -> int | None:
    """The whole number at node `name` of `fs`; None when absent."""
    node = fs.getNode(name)
    if node.empty():
        return None
    # real() of a string or a list is DBL_MAX, not an error, so only numeric nodes may use it.
    return _opt_int(node.real() if node.isInt() or node.isReal() else node.string(), name)


def _camera_from_filestorage(text: str, path: Path) -> Camera:
    """Camera from `text`, an OpenCV FileStorage YAML or JSON read from `path`. Parsed from the text,
    not the file: OpenCV's own reading fails on the byte-order mark Windows editors write."""
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except SystemError as exc:  # OpenCV 5's binding wraps the cv2.error of a file it cannot parse
        if not isinstance(exc.__cause__, cv2.error):
            raise
        raise exc.__cause__ from None
    try:
        K = _filestorage_matrix(fs, ("camera_matrix", "K", "cameraMatrix"))
        if K is None:
            raise CameraError("no camera_matrix, K or cameraMatrix node")
        dist = _filestorage_matrix(fs, ("distortion_coefficients", "D", "dist_coeffs", "distCoeffs"))
        width, height = _filestorage_int(fs, "image_width"), _filestorage_int(fs, "image_height")
    finally:
        fs.release()
    return Camera(K, np.zeros(5) if dist is None else dist.ravel(), width, height, f"file:{path}")


def load_camera(path: str | Path) -> Camera:
    """Read a ROS camera_info YAML (the calibration file, or the message as `ros2 topic echo` prints it),
    an OpenCV FileStorage YAML/JSON, or JSON `{fx, fy, cx, cy, dist}`."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")  # with or without the byte-order mark (BOM)
    except FileNotFoundError:
        raise CameraError(f"camera file not found: {path}") from None
    except UnicodeDecodeError:
        raise CameraError(f"camera file {path} is not text") from None
    try:
        return _parse_camera(text, path)
    except CameraError as exc:
        raise CameraError(f"{path}: {exc}") from None


def _parse_camera(text: str, path: Path) -> Camera:
    """Camera from the `text` of the camera file `path`; CameraError messages leave the path to the caller."""
    if not text.strip():
        raise CameraError(EMPTY_FILE)
    if text.lstrip().startswith("%YAML") or "!!opencv-matrix" in text or '"type_id": "opencv-matrix"' in text:
        try:
            return _camera_from_filestorage(text, path)
        except cv2.error as exc:
            raise CameraError(f"not a readable OpenCV FileStorage file ({_opencv_error(exc)})") from None
    try:
        # YAML is a superset of JSON. `ros2 topic echo` ends each message with "---", which starts
        # another (empty) document; without --once it prints one after the other: the first is used.
        data = next((d for d in yaml.safe_load_all(text) if d is not None), None)
    except yaml.YAMLError as exc:
        raise CameraError(f"neither valid YAML nor JSON ({_yaml_error(exc)})") from None
    if not isinstance(data, dict):
        raise CameraError("expected a mapping with camera_matrix or k (ROS camera_info) or fx, fy, cx, cy")
    if "camera_matrix" in data or is_ros_message(data):
        return camera_from_ros(data, f"file:{path}")
    if "fx" in data:
        return camera_from_json(data, f"file:{path}")
    raise CameraError("expected camera_matrix (ROS camera_info file), k (ROS 2 camera_info message, as "
                      "`ros2 topic echo --once` prints it) or fx, fy, cx, cy keys")


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
        # Its "function" is "<path>(<line>): <reason>", and the path may be a temporary upload's.
        parse = re.search(r"\((\d+)\): (.*)$", exc.func or "")
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
