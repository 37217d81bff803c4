"""The camera every image is run with: intrinsics typed in or a camera file uploaded, the file of
the camera in use, and the field of view assumed for images without camera or EXIF."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException, Request, status
from starlette.concurrency import run_in_threadpool

from signpose.pipeline.camera import camera_from_json, read_camera

from ..api_models import AssumedFovIn, CameraModel, CameraOut
from ..responses import camera_out
from ..uploads import read_upload, the_file
from .deps import JSON_BODY, JsonBodyRoute, WorkspaceDep

router = APIRouter(tags=["camera"], route_class=JsonBodyRoute)


@router.get("/camera", response_model=CameraOut)
def get_camera(workspace: WorkspaceDep) -> CameraOut:
    return camera_out(workspace)


@router.put("/camera", response_model=CameraOut, openapi_extra={"requestBody": {
    "required": True,
    "description": "JSON intrinsics {fx, fy, cx, cy, ...}, or the keys of a JSON camera file (K or camera_matrix, "
                   "D or distortion_coefficients, ...), read as a camera file of the same content is (a key it "
                   "refuses, such as k1, is 422); or a camera file uploaded",
    "content": {
        "application/json": {"schema": CameraModel.model_json_schema()},
        "multipart/form-data": {"schema": {
            "type": "object", "required": ["file"],
            "properties": {"file": {"type": "string", "format": "binary",
                                    "description": "ROS camera_info YAML (file, or message as ros2 topic echo "
                                                   "prints it), OpenCV FileStorage YAML/XML/JSON, a Kalibr "
                                                   "camchain of one camera, or {fx, fy, cx, cy}"}},
        }},
    },
}})
async def put_camera(request: Request, workspace: WorkspaceDep) -> CameraOut:
    """Set the camera from JSON intrinsics or an uploaded camera file; every image is re-run."""
    content_type = request.headers.get("content-type", "")
    if content_type.startswith("multipart/form-data"):
        async with request.form() as form:
            name, data = await run_in_threadpool(read_upload, the_file(form), "camera")
        camera = await run_in_threadpool(read_camera, data, name, f"upload:{name}")
    elif content_type.startswith("application/json"):
        # Read as every route reads its body (JsonBodyRequest), not by pydantic's parser, which takes the
        # last of a key given twice without a word; then as a camera file of the same content is, not by
        # CameraModel (the body's schema for /docs), which dropped the keys it has not (D beside fx: no
        # distortion; k1, a fisheye model) without a word.
        camera = camera_from_json(await request.json(), source="json")
    else:
        raise HTTPException(status.HTTP_415_UNSUPPORTED_MEDIA_TYPE,
                            "send JSON intrinsics {fx, fy, cx, cy, dist, width, height} "
                            "or a multipart camera file in the field 'file'")
    await run_in_threadpool(workspace.set_camera, camera)
    return await run_in_threadpool(camera_out, workspace)


@router.get("/camera/file", responses={404: {"description": "no camera is set"}})
def get_camera_file(workspace: WorkspaceDep) -> dict[str, Any]:
    """The camera in use as a JSON camera file gives it, which PUT /api/camera takes back as it is:
    a camera of part of its sensor as the whole sensor's intrinsics and size with its `roi` and
    `binning_x`, `binning_y`, where GET /api/camera gives those of the images."""
    camera = workspace.snapshot.camera
    if camera is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            "no camera is set: each image uses its EXIF focal length, else the assumed field of view")
    return camera.file_json()


@router.delete("/camera", response_model=CameraOut)
def delete_camera(workspace: WorkspaceDep) -> CameraOut:
    """Forget the camera: per image, its EXIF focal length if it has one, else the assumed field of view."""
    workspace.set_camera(None)
    return camera_out(workspace)


@router.put("/camera/assumed", response_model=CameraOut, dependencies=[JSON_BODY])
def put_assumed_fov(body: AssumedFovIn, workspace: WorkspaceDep) -> CameraOut:
    """The horizontal field of view to assume for images without camera or EXIF; they are re-run."""
    workspace.set_assumed_hfov(body.hfov_deg)
    return camera_out(workspace)
