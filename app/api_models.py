"""Request and response models of the signpose HTTP API (docs/web-contract.md), for validation and /docs."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field

from pipeline.library import LibrarySign
from pipeline.settings import Settings


class Health(BaseModel):
    status: Literal["ok"] = "ok"
    version: str
    images: int
    busy: bool = Field(description="whether any image is being (re-)processed")


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

    @classmethod
    def of(cls, sign: LibrarySign) -> SignOut:
        return cls(**sign.to_json())


class ImageSummary(BaseModel):
    id: str
    name: str
    expected: str | None = Field(description='a sign id, "none" for an image without a sign, or null: unlabelled')
    label: str | None
    recognized: bool
    inliers: int
    margin: int
    status: Literal["correct", "wrong", "recognized", "none", "pending", "error"]
    settings_version: int = Field(description="settings version the result was computed under (0: none yet)")
    width: int
    height: int
    error: str | None


class ImagesOut(BaseModel):
    version: int
    running: bool
    images: list[ImageSummary]


class UploadOut(BaseModel):
    images: list[ImageSummary]


class ScoreOut(BaseModel):
    sign: str
    matches: int
    inliers: int
    reason: str | None


class RecognitionOut(BaseModel):
    """The CLI's JSON for one image (`signpose recognize --json`)."""

    image: str
    recognized: bool
    label: str | None
    scores: list[ScoreOut]
    homography: list[list[float | None]] | None = Field(description="3x3, library px -> image px")
    corners: list[list[float | None]] | None = Field(description="4x2 image px: TL, TR, BR, BL")
    pose: dict[str, Any] | None
    timing_ms: dict[str, float]
    warnings: list[str]


class CameraModel(BaseModel):
    """Pinhole intrinsics in px; `dist` OpenCV's (k1, k2, p1, p2[, k3, ...])."""

    fx: float
    fy: float
    cx: float
    cy: float
    dist: list[float] = []
    width: int | None = Field(None, description="image width the intrinsics are for, px")
    height: int | None = None


class CameraIntrinsics(CameraModel):
    source: str


class CameraOut(BaseModel):
    camera: CameraIntrinsics | None = Field(
        description="null: per image, its EXIF focal length if it has one, else a 60° horizontal field of view")


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


class ExpectedIn(BaseModel):
    expected: str | None = Field(description='a sign id, "none" for an image without a sign, or null / ""')


class CalibrateIn(BaseModel):
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
    values: list[float]
    correct: list[int] = Field(description="labelled images recognised correctly, per value")
    min_margin: list[int | None] = Field(description="smallest inlier margin among correct recognitions, per value")
    band: tuple[float, float] | None = Field(
        description="the longest run of values where every labelled image is right")
    centre: float | None
    labelled: int
