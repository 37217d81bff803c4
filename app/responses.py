"""The answers of `signpose serve`'s API, shaped from the workspace and the calibration session
into the models of app/api_models.py. Each reads what it shows once, so that a result, its
summary and the settings it names come from the same run.
"""

from __future__ import annotations

import math

from fastapi import HTTPException, status

from signpose.pipeline.calibrate import MAX_SQUARE_M, MIN_VIEWS
from signpose.pipeline.camera import Camera, CameraError
from signpose.pipeline.exif import turned_camera
from signpose.pipeline.pose import euler_zyx_deg, quaternion_wxyz

from .api_models import (MappedSignOut, MapOut, RejectedOut, AttemptOut, BoardSearchOut, BoardSpec, CalibrationOut, CalibrationResult, CalibrationView,
                         CameraIntrinsics, CameraOut, ImageDetail, ImageSummary, SettingsOut)
from .calibration import CalibrationSession, CalibrationState, calibrated_camera, page_outlier_advice
from .image_store import ImageRecord, Outcome, status_of
from .sign_maps import HeldMap
from .workspace import Workspace


def result_of(record: ImageRecord) -> Outcome:
    """The image's latest outcome that has a result (possibly from older settings); 409 while there is none.

    Read once: the result and its settings version must come from the same run.
    """
    outcome = record.outcome
    if outcome.recognition is not None:
        return outcome
    if outcome.error is not None:
        raise HTTPException(status.HTTP_409_CONFLICT, f"{record.name}: {outcome.error}")
    raise HTTPException(status.HTTP_409_CONFLICT, f"{record.name} is still being processed; try again in a moment")


def summary(workspace: Workspace, record: ImageRecord, outcome: Outcome | None = None) -> ImageSummary:
    """The image's summary from `outcome` (default: its latest). A sign the plaque fallback found
    has no feature inliers or margin (null, as the CLI's table shows '-'), but its correlation."""
    outcome = record.outcome if outcome is None else outcome
    rec = outcome.recognition
    by_plaque = bool(rec and rec.by_plaque)
    return ImageSummary(
        id=record.id, name=record.name, expected=record.expected,
        label=rec.label if rec else None, recognized=bool(rec and rec.recognized),
        inliers=None if by_plaque else rec.best.n_inliers if rec and rec.best else 0,
        margin=None if by_plaque else rec.margin if rec else 0,
        by_plaque=by_plaque, plaque_correlation=round(rec.plaque.correlation, 4) if by_plaque else None,
        status=status_of(record.expected, outcome, workspace.snapshot.generation),
        settings_version=outcome.settings_version, result_version=outcome.generation,
        width=record.width, height=record.height, error=outcome.error,
    )


def detail(workspace: Workspace, record: ImageRecord) -> ImageDetail:
    """The image's summary with its latest result, the settings and camera it was computed with, and
    every region tried."""
    outcome = record.outcome  # once: summary, result and settings must come from the same run
    rec = outcome.recognition
    attempts = [] if rec is None else [
        AttemptOut(source=a.source, region=a.region, margin=a.margin,
                   winner=a.scores[a.winner].sign if a.winner is not None else None)
        for a in rec.attempts
    ]
    return ImageDetail(**summary(workspace, record, outcome).model_dump(),
                       result=rec.to_json(record.name) if rec else None, settings=rec.settings if rec else None,
                       camera=intrinsics(rec.camera) if rec else None, attempts=attempts)


def settings_out(workspace: Workspace) -> SettingsOut:
    """The current settings and their version."""
    snap = workspace.snapshot
    return SettingsOut(version=snap.settings_version, settings=snap.settings)


def camera_kind(camera: Camera) -> str:
    """Where intrinsics came from, for people (CameraIntrinsics.kind), from their `source`."""
    if camera.is_assumed:
        return "assumed"
    if camera.is_exif:
        return "exif"
    for prefix, kind in (("calibrat", "calibration"), ("json", "typed")):
        if camera.source.startswith(prefix):
            return kind
    return "file"  # file:<path>, upload:<name>, or a camera made by a script


def intrinsics(camera: Camera | None) -> CameraIntrinsics | None:
    return None if camera is None else CameraIntrinsics(**camera.to_json(), kind=camera_kind(camera))


def misfit_warnings(camera: Camera | None, images: list[ImageRecord]) -> list[str]:
    """Why `camera` cannot be used for some of `images` (they will fail), in the words of the first
    one's CameraError. The camera is kept all the same: it may be meant for photos still to come."""
    if camera is None:
        return []
    failures: dict[tuple[int, int, int], str] = {}  # (width, height, EXIF orientation) -> why not
    for kind in {(r.width, r.height, r.exif.orientation) for r in images}:
        width, height, orientation = kind
        try:
            turned_camera(camera, orientation, width, height).for_image(width, height)
        except CameraError as exc:
            failures[kind] = str(exc)
    misfits = [failures[key] for r in images if (key := (r.width, r.height, r.exif.orientation)) in failures]
    if not misfits:
        return []
    which = "fits none" if len(misfits) == len(images) else f"does not fit {len(misfits)}"
    return [f"the camera {which} of the {len(images)} images held: {misfits[0]}"]


def camera_out(workspace: Workspace) -> CameraOut:
    """The camera in use (None: per image, EXIF or the assumed field of view), and why it fits
    some of the images held badly."""
    snap = workspace.snapshot
    images = workspace.images()
    return CameraOut(camera=intrinsics(snap.camera), assumed_hfov_deg=snap.assumed_hfov_deg,
                     exif_images=sum(r.exif.camera is not None for r in images),
                     warnings=misfit_warnings(snap.camera, images))


def calibration_out(calibration: CalibrationSession, state: CalibrationState) -> CalibrationOut:
    """The response for `state`, a state of `calibration` (read once by the caller: photos, board
    and result must agree)."""
    summary = state.result.to_json() if state.result is not None else None
    # Without a result, the photos the last run dropped as outliers are still out (`unfitted` counts without them).
    left_out = state.recipe.left_out if state.recipe else frozenset()
    other_sizes = state.other_sizes
    views = [CalibrationView(**(summary["views"][i] if summary else
                                {"name": p.name, "found": p.view.found, "excluded": p.id in left_out}),
                             id=p.id, width=p.view.image_size[0], height=p.view.image_size[1],
                             other_size=other_sizes.get(p.id))
             for i, p in enumerate(state.photos)]
    result = None if summary is None else CalibrationResult.model_validate(
        {**summary, "camera": intrinsics(calibrated_camera(state.result)),
         "outlier_advice": page_outlier_advice(state.result)})
    search = calibration.search
    return CalibrationOut(revision=state.revision, min_views=MIN_VIEWS, max_views=calibration.max_photos,
                          max_square_m=MAX_SQUARE_M, views=views,
                          hint=state.few_boards_advice,
                          board=BoardSpec(cols=state.board[0], rows=state.board[1], square_m=state.square_m),
                          search=None if search is None else BoardSearchOut(**search.to_json()),
                          result=result, unfitted=state.unfitted, size_mismatch=state.size_mismatch)


def map_out(held: HeldMap) -> MapOut:
    """The map held as GET /api/map gives it: each sign's pose, covariance and worst-direction 1-sigma,
    and for a map built here how the survey saw each sign and what it rejected."""
    report = held.report
    signs = []
    for sign in held.sign_map.signs.values():
        sigma = sign.worst_sigma()
        seen = report.signs.get(sign.sign_id) if report is not None else None
        signs.append(MappedSignOut(
            id=sign.sign_id, position_m=[float(v) for v in sign.position_m],
            orientation_wxyz=[float(v) for v in quaternion_wxyz(sign.R)],
            yaw_pitch_roll_deg=[float(v) for v in euler_zyx_deg(sign.R)],
            covariance=None if sign.covariance is None else sign.covariance.tolist(),
            sigma_position_m=None if sigma is None else sigma[0],
            sigma_rotation_deg=None if sigma is None else math.degrees(sigma[1]),
            fixed=seen.fixed if seen is not None else None, images=seen.images if seen is not None else None,
            seen_with=seen.seen_with if seen is not None else None))
    if report is None:
        return MapOut(frame=held.sign_map.frame, source=held.source, revision=held.revision, signs=signs)
    return MapOut(frame=held.sign_map.frame, source=held.source, revision=held.revision, signs=signs,
                  rejected=[RejectedOut(image=image, sign=sign, chi2=chi2) for image, sign, chi2 in report.rejected],
                  unmapped=report.unmapped, warnings=list(report.warnings))
