"""The camera located in the map frame, measured against a survey's truth (`signpose evaluate --map`).

A survey folder, as `pipeline.synth_survey` writes it, holds its photos and a truth.json with each
photo's camera pose in the map frame: {"photos": [{"image", "R", "t" (X_cam = R·X_map + t), ...}]}.
Every sign in each photo is recognised (`recognize_every_sign`), the camera located from the mapped
ones (`locate_in_map`), and its position and rotation compared with the truth.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .camera import Camera, CameraError
from .every_sign import recognize_every_sign
from .evaluate import DatasetError, ImageCheck, _matrix, _percentiles
from .image import ImageError, decode_image, read_file
from .jsonfile import read_json
from .library import Library
from .localise import locate_in_map
from .pose import camera_position, rotation_error_deg
from .recognize import PipelineError, pipeline_errors
from .settings import Settings
from .sign_map import SignMap


@dataclass(frozen=True)
class SurveyPhoto:
    """A photo of a survey and its camera's true pose in the map frame: X_cam = R·X_map + t (R (3, 3), t (3,) m)."""

    path: Path
    R: np.ndarray
    t: np.ndarray


@dataclass(frozen=True)
class PhotoInMap:
    """One photo located: the errors of the camera's position (m) and rotation (degrees) against the truth,
    None when no mapped sign was seen; `error` when the photo could not be used."""

    photo: SurveyPhoto
    position_error_m: float | None = None
    rotation_error_deg: float | None = None
    error: str | None = None


def survey_photos(root: Path) -> list[SurveyPhoto] | None:
    """The photos of the survey folder `root` with their true poses, None when its truth gives no camera
    poses in the map frame (no truth.json, or one of labelled images). DatasetError for a survey truth
    naming a photo that is not there or a pose that is not numbers."""
    truth_path = root / "truth.json"
    if not truth_path.is_file():
        return None
    truth = read_json(truth_path, DatasetError)
    entries = truth.get("photos") if isinstance(truth, dict) else None
    if not isinstance(entries, list):
        return None
    photos = []
    for i, entry in enumerate(entries):
        where = f"{truth_path} photos[{i}]"
        if not isinstance(entry, dict) or not isinstance(entry.get("image"), str):
            raise DatasetError(f'{where}: each photo needs "image" (a file name), "R" and "t"')
        R, t = _matrix(entry.get("R"), (3, 3), f"{where}: R"), _matrix(entry.get("t"), (3,), f"{where}: t")
        if R is None or t is None or not (root / entry["image"]).is_file():
            raise DatasetError(f"{where}: needs R, t and the photo {entry['image']!r} in {root}")
        photos.append(SurveyPhoto(root / entry["image"], R, t))
    return photos


def locate_photos(photos: list[SurveyPhoto], library: Library, settings: Settings, camera: Camera | None,
                  sign_map: SignMap, check_image: ImageCheck | None = None) -> Iterator[PhotoInMap]:
    """Each photo's camera located in `sign_map`'s frame and compared with its truth, in order. `camera`: the
    survey's intrinsics (None: an assumed field of view)."""
    for photo in photos:
        try:
            data = read_file(photo.path)
            if check_image is not None:
                check_image(data, str(photo.path))
            image = decode_image(data, str(photo.path))
            with pipeline_errors(str(photo.path)):
                found = [r for r in recognize_every_sign(image, library, settings, camera) if r.label is not None]
                located = (locate_in_map(found=found, sign_map=sign_map, library=library, camera=found[0].camera)
                           if found else None)
        except (ImageError, CameraError, PipelineError) as exc:
            yield PhotoInMap(photo, error=str(exc))
            continue
        if located is None:
            yield PhotoInMap(photo)
            continue
        yield PhotoInMap(photo, float(np.linalg.norm(located.position_m - camera_position(photo.R, photo.t))),
                         rotation_error_deg(located.R, photo.R.T))


def summary_in_map(results: list[PhotoInMap]) -> dict:
    """{"photos", "located", "position_error_m", "rotation_error_deg"} over `results`, errors as
    {"median", "p90"} or null."""
    def pair(values: list[float]) -> dict | None:
        figures = _percentiles(values)
        return None if figures is None else {"median": figures[0], "p90": figures[1]}

    located = [r for r in results if r.position_error_m is not None and r.rotation_error_deg is not None]
    return {"photos": len(results), "located": len(located),
            "position_error_m": pair([r.position_error_m for r in located if r.position_error_m is not None]),
            "rotation_error_deg": pair([r.rotation_error_deg for r in located if r.rotation_error_deg is not None])}


def format_map_table(summaries: dict[str, dict], frame: str) -> str:
    """The table of the camera in the map frame `frame`, a row per survey of `summaries` (`summary_in_map`)."""
    def pair(figures: dict | None, scale: float, unit: str) -> str:
        return "-" if figures is None else f"{scale * figures['median']:.2f} / {scale * figures['p90']:.2f}{unit}"

    width = max(16, *(len(name) + 2 for name in summaries))
    head = f"{'survey':<{width}}{'photos':>7}{'located':>8}   {'position med/p90':>19}{'rotation med/p90':>19}"
    lines = [f"camera in the map frame ({frame})", head, "-" * len(head)]
    lines += [f"{name:<{width}}{s['photos']:>7}{s['located']:>8}   {pair(s['position_error_m'], 100, ' cm'):>19}"
              f"{pair(s['rotation_error_deg'], 1, '°'):>19}" for name, s in summaries.items()]
    return "\n".join(lines)
