"""Request and response models of the signpose HTTP API (docs/web-contract.md), for validation and /docs."""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field
from pydantic_core import PydanticCustomError

from signpose.pipeline.library import LibrarySign
from signpose.pipeline.settings import Settings


# Text that is a JSON number as written, short enough to quote back in an error.
QUOTED_NUMBER = re.compile(r"-?(0|[1-9][0-9]*)(\.[0-9]+)?([eE][+-]?[0-9]+)?")


def json_number(value: Any) -> Any:
    """`value` unless it is text or true/false: pydantic's lax mode would read "500" as 500 and true as
    1, so a client quoting its numbers, or sending a checkbox's state, would go unnoticed."""
    if isinstance(value, (str, bool)):
        raise PydanticCustomError("number_type", "Input should be a number, not {what}",
                                  {"what": _unquoted(value) if isinstance(value, str) else "true or false"})
    return value


def _unquoted(text: str) -> str:
    """How to write the number quoted as `text`: that number without its quotes ("9": write 9, not "9"), or any
    number when it is none."""
    if len(text) <= 32 and QUOTED_NUMBER.fullmatch(text):
        return f'text: write {text}, not "{text}"'
    return "text: write a number without quotes"


# Numbers in request bodies: JSON numbers only (a whole number may be written 640.0).
Number = Annotated[float, BeforeValidator(json_number)]
WholeNumber = Annotated[int, BeforeValidator(json_number)]


class RequestBody(BaseModel):
    """A JSON body a route takes: a key it does not read is refused (422 naming it), not dropped without a word."""

    model_config = ConfigDict(extra="forbid")


class Health(BaseModel):
    status: Literal["ok"] = "ok"
    version: str
    images: int
    busy: bool = Field(description="whether any image is being (re-)processed")
    memory_held_bytes: int = Field(description="memory the images held take, bytes, as the memory limit counts "
                                               "it (5 bytes a pixel plus 1 MB an image)")
    memory_limit_bytes: int = Field(description="the memory limit (--max-memory-gb), bytes: uploads that would "
                                                "take more are refused")


class SettingsOut(BaseModel):
    version: int = Field(description="settings_version: +1 on every accepted change")
    settings: Settings


class SettingField(BaseModel):
    name: str
    type: Literal["float", "int", "bool", "choice"]
    group: str
    default: Any
    min: float | None = None
    max: float | None = None
    step: float | None = None
    choices: list[str] | None = None
    help: str
    nullable: bool = False


class SignOut(BaseModel):
    id: str
    name: str
    text: str
    image: str = Field(description="image file name inside the library folder")
    width_m: float
    height_m: float
    kind: Literal["plaque", "picture"] = Field(description="a plaque of text, checked against plaques of other "
                                                           "words, or a textured picture")
    min_text_correlation: float | None = Field(None, description="the text check's bar for this sign; null: the "
                                                                 "settings' min_text_correlation")

    @classmethod
    def of(cls, sign: LibrarySign) -> SignOut:
        return cls(**sign.to_json())


class ImageSummary(BaseModel):
    id: str
    name: str
    expected: str | None = Field(description='a sign id, "none" for an image without a sign, or null: unlabelled')
    label: str | None
    recognized: bool
    inliers: int | None = Field(description="RANSAC inliers of the recognised sign (0 without one); null when the "
                                            "plaque fallback recognised it, which matches no features")
    margin: int | None = Field(description="inlier margin over the runner-up; null when the plaque fallback decided")
    by_plaque: bool = Field(False, description="the plaque fallback, not feature matches, recognised the sign")
    plaque_correlation: float | None = Field(None, description="with by_plaque: the plaque's correlation with the "
                                                               "sign (0 to 1), what decided instead of inliers")
    status: Literal["correct", "wrong", "recognized", "none", "pending", "error"]
    settings_version: int = Field(description="settings version the result was computed under (0: none yet)")
    result_version: int = Field(description="state generation the result was computed under: changes whenever the "
                                            "image is re-run (a settings, camera or library change); -1: none yet")
    width: int
    height: int
    error: str | None


class ImagesOut(BaseModel):
    version: int
    running: bool
    images: list[ImageSummary]


class UploadOut(BaseModel):
    images: list[ImageSummary]


class ImagesRemoved(BaseModel):
    removed: int = Field(description="how many images there were; any that land later are kept")


class ScoreOut(BaseModel):
    sign: str
    matches: int
    inliers: int
    reason: str | None


class TextCheckOut(BaseModel):
    strips: list[float | None] = Field(description="correlation in each of 6 strips across the sign, left to "
                                                   "right on it; null: mostly outside the image")
    weakest: float | None
    continued: list[str] = Field(description="sides ('left', 'right', 'above', 'below') beyond which the plaque "
                                             "and its text go on: a plaque of the sign's words and more")
    washed_out: list[int] = Field(description="strips (0-5, left to right) not judged as glare washed their ink out")


class TurnedDownOut(BaseModel):
    sign: str
    source: str = Field(description="where it was found: 'blob 1', 'plaque 2', 'full frame', 'plaque fallback', ...")
    text_check: TextCheckOut


class RecognitionOut(BaseModel):
    """The CLI's JSON for one image (`signpose recognize --json`)."""

    image: str
    recognized: bool
    label: str | None
    scores: list[ScoreOut]
    homography: list[list[float | None]] | None = Field(description="3x3, library px -> image px")
    corners: list[list[float | None]] | None = Field(description="4x2 image px: TL, TR, BR, BL")
    pose: dict[str, Any] | None
    text_check: TextCheckOut | None = Field(description="the recognised sign's text against the library's "
                                                        "(null: not checked, min_text_correlation 0)")
    turned_down: list[TurnedDownOut] = Field(description="winners whose text the check turned down, in the "
                                                         "order found")
    timing_ms: dict[str, float]
    reused_stages: list[str] = Field(description="stages whose results came from the image's cache (their "
                                                 "times are a lookup's); empty in the CLI")
    warnings: list[str]
    signs: list[dict[str, Any]] | None = Field(None, description="every library sign found in the image, each "
                                               "{label, corners, pose}, the answer first, as `signpose recognize "
                                               "--json` gives them; POST /api/recognize (null in an image's "
                                               "result)")
    camera_in_map: dict[str, Any] | None = Field(None, description="while a sign map is held: the camera in the "
                                                 "map frame from one fit over the mapped signs in view, as "
                                                 "`signpose recognize --map` gives it (null: none in view, or no map)")


class PinholeModel(BaseModel):
    """Pinhole intrinsics in px; `dist` OpenCV's (k1, k2, p1, p2[, k3, ...])."""

    fx: Number
    fy: Number
    cx: Number
    cy: Number
    dist: list[Number] = []
    width: WholeNumber | None = Field(None, description="image width the intrinsics are for, px; with height, "
                                                        "or neither (then they are never scaled to an image)")
    height: WholeNumber | None = Field(None, description="image height the intrinsics are for, px; with width")


class RoiModel(BaseModel):
    """ROS's CameraInfo.roi: the part of the sensor the images are, in px of the full, unbinned sensor."""

    x_offset: WholeNumber
    y_offset: WholeNumber
    width: WholeNumber
    height: WholeNumber


class CameraModel(PinholeModel):
    """PUT /api/camera's JSON, as its OpenAPI schema: intrinsics for images of width x height px, or, with `roi`
    or binning, those of the whole sensor (full resolution, unbinned) with the part of it the images are, as
    ROS's CameraInfo gives them. The body is read by pipeline.camera.camera_from_json, as a camera file of the
    same content is (its other keys too), not validated by this model, which would drop what it has not."""

    roi: RoiModel | None = Field(None, description="the part of the sensor the images are (x_offset, y_offset, "
                                                   "width, height px of the full sensor); all zeros: all of it")
    binning_x: WholeNumber | None = Field(None, description="sensor px summed into an image px across (0 or 1: none)")
    binning_y: WholeNumber | None = Field(None, description="sensor px summed into an image px down (0 or 1: none)")


class CameraIntrinsics(PinholeModel):
    """The intrinsics images are taken with: for a camera given with a roi or binning, those of the part of
    the sensor they are, for their size."""

    source: str = Field(description='where the numbers came from, e.g. "upload:cam.yaml", "json", '
                                    '"calibration: 15 views, RMS 0.21 px", "EXIF focal length 4.2 mm", '
                                    '"assumed 60° horizontal field of view"')
    kind: Literal["calibration", "file", "typed", "exif", "assumed"] = Field(
        description="the source for people: chessboard calibration, a camera file, intrinsics typed in "
                    "(PUT /api/camera JSON), the photo's EXIF focal length, or an assumed field of view")


class CameraOut(BaseModel):
    camera: CameraIntrinsics | None = Field(
        description="null: per image, its EXIF focal length if it has one, else assumed_hfov_deg")
    assumed_hfov_deg: float = Field(description="horizontal field of view assumed for images without camera or EXIF")
    exif_images: int = Field(description="images with an EXIF focal length, which they use while camera is null")
    warnings: list[str] = Field(description="images held that the camera does not fit (they fail), and why; the "
                                            "camera is kept all the same, as it may be for photos still to come")


class AssumedFovIn(RequestBody):
    hfov_deg: Number = Field(description="horizontal field of view, degrees (10 to 140)")


class CanvasScaleIn(RequestBody):
    width: WholeNumber = Field(ge=1, le=100_000, description="width of the 3D view's canvas as viser reports it: "
                                                             "device px")
    height: WholeNumber = Field(ge=1, le=100_000, description="its height, device px")
    px_per_css_px: Number = Field(gt=0, le=100, description="its device px to the CSS px: the screen's "
                                  "devicePixelRatio, or less while viser lowers its resolution to keep its frame rate")


class BoardSpec(BaseModel):
    """A printed chessboard: inner corners (where four squares meet) across and down, and the square side."""

    cols: WholeNumber = Field(description="inner corners across: squares across minus one (3 to 100)")
    rows: WholeNumber = Field(description="inner corners down: squares down minus one (3 to 100)")
    square_m: Number = Field(description="side of one printed square as measured on the print, metres")


class CalibrationView(BaseModel):
    id: str
    name: str
    width: int
    height: int
    found: bool = Field(description="whether the board was found in the photo")
    error_px: float | None = Field(None, description="RMS reprojection error of this photo under the fitted "
                                                     "camera, px; null until calibrated or when not found")
    tilt_deg: float | None = Field(None, description="angle between the board's normal and the optical axis")
    outlier: bool = Field(False, description="error far above the others' (above outlier_threshold_px)")
    excluded: bool = Field(False, description="left out of the fit as an outlier (run with drop_outliers); it stays "
                                              "out as photos are removed, also while those left give no result "
                                              "(`unfitted`), until the next run")
    other_size: str | None = Field(None, description="when the board was found in this photo but the photo is not "
                                                     "the size most photos with the board share: its size and "
                                                     "theirs, \"640x480, the others 1280x960\" (a calibration "
                                                     "holds for one size, so a run is refused: see size_mismatch); "
                                                     "null otherwise")


class IntrinsicsStd(BaseModel):
    """Standard deviations of the fitted intrinsics, px."""

    fx: float
    fy: float
    cx: float
    cy: float


class CalibrationResult(BaseModel):
    rms_px: float = Field(description="RMS reprojection error over every corner of the photos fitted, px")
    camera: CameraIntrinsics
    intrinsics_std: IntrinsicsStd
    outlier_threshold_px: float
    used: int = Field(description="photos the intrinsics were fitted to")
    warnings: list[str] = Field(description="reasons to distrust the result, each with what to do")
    outlier_advice: str | None = Field(
        None, description="what to do about the outliers, in the words of the page's Camera dialog (its drop "
                          "outliers button, a photo's ×): drop them, or, once dropped, retake or remove those the "
                          "refit flags; null without outliers")


class BoardSearchOut(BaseModel):
    cols: int
    rows: int
    done: int = Field(description="photos searched so far")
    total: int = Field(description="photos to search")


class CalibrationOut(BaseModel):
    revision: int = Field(description="+1 on every change; an answer with a lower one is out of date")
    board: BoardSpec
    search: BoardSearchOut | None = Field(
        None, description="while a new board size (PUT /api/calibration/board) is searched for in every photo, "
                          "how far it has come (board, views and result are the ones before it until it is done); "
                          "null otherwise")
    min_views: int = Field(description="photos with the board found that a calibration needs at least")
    max_views: int = Field(description="photos the calibration holds at most")
    max_square_m: float = Field(description="largest board square, metres: beyond, the size was typed in millimetres")
    views: list[CalibrationView] = Field(description="in the order chosen (`batch`, `position`)")
    hint: str | None = Field(None, description="what to do when the board is found in too few of the photos to "
                                               "calibrate: check its size (often given in squares rather than inner "
                                               "corners) when it is found in fewer than half of them, else add "
                                               "photos; null otherwise")
    result: CalibrationResult | None = Field(
        description="null until run, and again after photos are added or the board changes; when a photo is "
                    "removed, fitted again to the photos left (the photos it left out stay out)")
    size_mismatch: str | None = Field(None, description="why the photos with the board cannot be calibrated "
                                                        "together, as a run would refuse: which are which other size "
                                                        "than most, how it differs and what to do; null when they are "
                                                        "all one size")
    unfitted: str | None = Field(None, description="why the photos left gave no result when they were fitted again "
                                                   "after a photo was removed, said anew after each removal since "
                                                   "the last run; null otherwise")


class CalibrationAdded(CalibrationOut):
    added: list[str] = Field(description="ids of the photos this request added, in its files' order: the "
                                         "views listed are in the order chosen, and names may repeat")


class CalibrationRunIn(RequestBody):
    drop_outliers: bool = Field(False, description="fit once more without the outliers of the first fit")


class AttemptOut(BaseModel):
    source: str
    region: tuple[int, int, int, int]
    winner: str | None
    margin: int


class ImageDetail(ImageSummary):
    result: RecognitionOut | None
    settings: Settings | None = Field(description="the settings the result was computed under: those of "
                                                  "settings_version (GET /api/settings?version=N)")
    camera: CameraIntrinsics | None = Field(description="intrinsics used for this image")
    attempts: list[AttemptOut]


class ExpectedIn(RequestBody):
    expected: str | None = Field(description='a sign id, "none" for an image without a sign, or null / ""')


class CalibrateIn(RequestBody):
    image_id: str
    rect: tuple[int, int, int, int] | None = Field(
        None, description="[x0, y0, x1, y1] image px around the sign; null: the detected sign or blob")


class CalibrateOut(BaseModel):
    white_level: float
    background_level: float | None
    suggested_threshold: float
    histogram: list[int] = Field(description="256 counts of the normalised gray inside the region, over [0, 1]")
    rect: tuple[int, int, int, int]
    source: Literal["rectangle", "detected sign", "blob"]
    warning: str | None


class SweepOut(BaseModel):
    param: str
    # int first: an integer setting's values, band and centre stay whole numbers in the JSON (4, not 4.0)
    values: list[int | float] = Field(description="the values run, in order: distinct whole numbers for an "
                                                  "integer setting")
    correct: list[int] = Field(description="labelled images recognised correctly, per value")
    min_margin: list[int | None] = Field(
        description="smallest inlier margin among the signs recognised correctly by feature matches, per value; "
                    "null if none (signs the plaque fallback recognised have no inliers and are left out)")
    by_plaque: list[int] = Field(description="of the labelled images right, those whose sign the plaque fallback "
                                             "recognised, per value")
    failed: list[int] = Field(description="labelled images the pipeline failed on, per value (counted as not "
                                          "right; the server's log says why)")
    band: tuple[int | float, int | float] | None = Field(
        description="the longest run of values where every labelled image is right")
    centre: int | float | None = Field(description="the middle of the band; for an integer setting the value swept "
                                                   "in the band nearest it")
    labelled: int


class FlightCamera(BaseModel):
    """The intrinsics a flight was tracked with, px."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int | None
    height: int | None
    source: str


class FlightOut(BaseModel):
    """A flight (app/flights.py): `status` queued | processing | done | error, `done` of `total` frames
    tracked (total null while not known), `frames` the frames of the last complete run, `cursor` the
    frame the page shows (the 3D scene's current frustum)."""

    id: str
    name: str
    kind: Literal["video", "bag"]
    status: Literal["queued", "processing", "done", "error"]
    done: int
    total: int | None
    frames: int
    width: int
    height: int
    fps: float | None
    error: str | None
    warnings: list[str]
    result_version: int
    cursor: int
    camera: FlightCamera | None


class FlightsOut(BaseModel):
    flights: list[FlightOut]


class FlightFramesOut(BaseModel):
    """Every frame's line of `signpose track --json` for the flight's last complete run."""

    id: str
    result_version: int
    frames: list[dict[str, Any]]


class FlightCursorIn(RequestBody):
    frame: WholeNumber = Field(ge=0, description="the frame shown, from 0")


class MappedSignOut(BaseModel):
    """One sign of the map held: X_map = R(orientation_wxyz)·X_sign + position_m (metres); `covariance`
    6x6 in ROS order (x, y, z, rotation about the map's x, y, z) or null; `sigma_position_m` and
    `sigma_rotation_deg`, its 1-sigma along its worst direction (null without a covariance). A map
    built here adds how the survey saw the sign: `fixed` ("anchor", else null), `images` that saw it
    and `seen_with` (the other signs in them, and in how many)."""

    id: str
    position_m: list[float]
    orientation_wxyz: list[float]
    yaw_pitch_roll_deg: list[float]
    covariance: list[list[float]] | None
    sigma_position_m: float | None
    sigma_rotation_deg: float | None
    fixed: str | None = None
    images: int | None = None
    seen_with: dict[str, int] | None = None


class RejectedOut(BaseModel):
    """An observation a build left out as inconsistent: `image` (a photo's or flight frame's name), its
    `sign` and its whitened squared residual `chi2`."""

    image: str
    sign: str
    chi2: float


class MapOut(BaseModel):
    """The sign map held: its `frame` id, `source` (the file's name, or what it was built from),
    `revision` (+1 on every change), `signs`, and for a map built here the observations `rejected`,
    the signs left out (`unmapped`: id -> why) and `warnings` (photos that could not be run)."""

    frame: str
    source: str
    revision: int
    signs: list[MappedSignOut]
    rejected: list[RejectedOut] = []
    unmapped: dict[str, str] = {}
    warnings: list[str] = []


class MapBuildIn(RequestBody):
    """`anchor`: the library sign whose frame is the map frame (null: the first sign seen)."""

    anchor: str | None = Field(default=None, max_length=64)
