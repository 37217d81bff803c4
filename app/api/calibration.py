"""Calibrating the camera from photos of a chessboard (app/calibration.py holds the session): add
and remove photos, set the board, run the fit, look at each photo, and use or download the result."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, File, HTTPException, Query, Response, UploadFile, status

from signpose.pipeline.calibrate import Calibration
from signpose.pipeline.camera import ros_camera_yaml

from .. import figures
from ..api_models import BoardSpec, CalibrationAdded, CalibrationOut, CalibrationRunIn, CameraOut
from ..calibration import PREVIEW_MAX_SIDE, CalibrationState, calibrated_camera
from ..responses import calibration_out, camera_out
from ..uploads import read_upload
from ..image_store import Conflict
from .deps import (FILES, IN_ORDER, JSON_BODY, MULTIPART, OPTIONAL_JSON_BODY, Batch, CalibrationDep, JsonBodyRoute,
                   Position, WorkQueueDep, WorkspaceDep)

router = APIRouter(tags=["calibration"], route_class=JsonBodyRoute)


def no_such_photo(view_id: str) -> HTTPException:
    return HTTPException(status.HTTP_404_NOT_FOUND,
                         f"no calibration photo with id {view_id!r}; GET /api/calibration lists them")


def fitted(state: CalibrationState) -> Calibration:
    """The state's calibration; 409 saying why there is none."""
    if state.result is None:
        raise Conflict(state.why_no_result)
    return state.result


@router.get("/calibration", response_model=CalibrationOut)
def get_calibration_state(calibration: CalibrationDep) -> CalibrationOut:
    """The board, every photo (board found or not, its error), and the result of the last run, if current."""
    return calibration_out(calibration, calibration.state)


@router.post("/calibration/images", response_model=CalibrationAdded, status_code=status.HTTP_201_CREATED,
             dependencies=[MULTIPART, FILES, IN_ORDER])
def add_calibration_photos(files: Annotated[list[UploadFile], File(description="photos of the chessboard")],
                           calibration: CalibrationDep, batch: Batch = "", position: Position = 0) -> CalibrationAdded:
    """Add photos and search each for the board (all or nothing). The last result is dropped.
    Listed after those held, or with `batch`, by `position` among its files; `added` names them."""
    state, added = calibration.add([read_upload(f) for f in files], batch, position)
    return CalibrationAdded(**calibration_out(calibration, state).model_dump(), added=added)


@router.delete("/calibration", response_model=CalibrationOut)
def clear_calibration(calibration: CalibrationDep) -> CalibrationOut:
    """Forget every calibration photo (the board size stays; the workspace camera is not touched)."""
    return calibration_out(calibration, calibration.clear())


@router.put("/calibration/board", response_model=CalibrationOut, dependencies=[JSON_BODY])
def set_calibration_board(body: BoardSpec, calibration: CalibrationDep) -> CalibrationOut:
    """Set the board; every photo is searched again when the corner counts change. 422 names a bad value."""
    return calibration_out(calibration, calibration.set_board((body.cols, body.rows), body.square_m))


@router.post("/calibration/run", response_model=CalibrationOut, dependencies=[OPTIONAL_JSON_BODY])
async def run_calibration(calibration: CalibrationDep, queue: WorkQueueDep,
                          body: CalibrationRunIn | None = None) -> CalibrationOut:
    """Fit the intrinsics to the photos where the board was found, on the board set (422 says why it
    cannot). The body is optional: without one, `drop_outliers` is false."""
    drop_outliers = (body or CalibrationRunIn()).drop_outliers
    # No time limit: a fit cannot stop part-way, and the session holds its lock while it runs.
    return await queue.run("the calibration", lambda _: calibration_out(calibration, calibration.run(drop_outliers)),
                           limit_s=None)


@router.get("/calibration/views/{view_id}/image",
            responses={200: {"content": {"image/jpeg": {}}, "description": "JPEG figure"}})
def get_calibration_view(view_id: str, calibration: CalibrationDep,
                         overlay: Annotated[Literal["corners", "undistorted"], Query(
                             description="corners: the corners found; undistorted: undistorted by the result")]
                         = "corners",
                         max_side: Annotated[int, Query(ge=32, le=PREVIEW_MAX_SIDE)] = PREVIEW_MAX_SIDE) -> Response:
    """One calibration photo with the board's corners drawn (header X-Calibration-Revision)."""
    state = calibration.state  # once: photo, board and result must agree
    try:
        photo = state.photo(view_id)
    except KeyError:
        raise no_such_photo(view_id) from None
    camera = fitted(state).camera if overlay == "undistorted" else None
    img = figures.draw_board(photo.preview, photo.view, state.board, camera, max_side)
    return Response(figures.jpeg(img), media_type="image/jpeg",
                    headers={"X-Calibration-Revision": str(state.revision)})


@router.delete("/calibration/views/{view_id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_calibration_view(view_id: str, calibration: CalibrationDep) -> None:
    """Forget one photo; after a run, the photos left are fitted again as it fitted them (those it left
    out stay out), after every removal; when they give no result, `unfitted` and the 409 of GET
    /api/calibration/camera.yaml say why."""
    try:
        calibration.remove(view_id)
    except KeyError:
        raise no_such_photo(view_id) from None


@router.post("/calibration/apply", response_model=CameraOut)
def apply_calibration(calibration: CalibrationDep, workspace: WorkspaceDep) -> CameraOut:
    """Use the calibrated camera for every image (as PUT /api/camera does); they are re-run."""
    workspace.set_camera(calibrated_camera(fitted(calibration.state)))
    return camera_out(workspace)


@router.get("/calibration/camera.yaml",
            responses={200: {"content": {"application/x-yaml": {}}, "description": "ROS camera_info YAML"}})
def get_calibration_yaml(calibration: CalibrationDep) -> Response:
    """The calibrated camera as a ROS camera_info file (signpose recognize --camera reads it)."""
    return Response(ros_camera_yaml(calibrated_camera(fitted(calibration.state))), media_type="application/x-yaml",
                    headers={"Content-Disposition": 'attachment; filename="camera.yaml"'})
