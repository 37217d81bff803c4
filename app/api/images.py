"""The images of the workspace: add (each run in the background), list, label, delete, fetch the
file and a figure of each pipeline stage; and one image recognised without keeping it."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, File, Form, HTTPException, Query, Response, UploadFile, status
from fastapi.responses import FileResponse
from starlette.concurrency import run_in_threadpool

from signpose.pipeline.every_sign import SignSeen

from .. import figures
from ..api_models import ExpectedIn, ImageDetail, ImagesOut, ImagesRemoved, ImageSummary, RecognitionOut, UploadOut
from ..responses import detail, result_of, summary
from ..sign_maps import in_view_json
from ..uploads import read_upload
from .deps import (FILES, IN_ORDER, JSON_BODY, MULTIPART, ONE_FILE, Batch, JsonBodyRoute, Position, RecordDep,
                   SignMapsDep, WorkQueueDep, WorkspaceDep)

router = APIRouter(tags=["images"], route_class=JsonBodyRoute)


@router.post("/images", response_model=UploadOut, status_code=status.HTTP_201_CREATED,
             dependencies=[MULTIPART, FILES, IN_ORDER])
def add_images(files: Annotated[list[UploadFile], File(description="one or more images")],
               workspace: WorkspaceDep,
               expected: Annotated[list[str], Form(description='a sign id, "none" (no sign in the photo) or "" '
                                                               '(unlabelled): one for every file, or one per file '
                                                               'in their order')] = [],  # noqa: B006 (FastAPI copies it per request; the schema shows it)
               batch: Batch = "", position: Position = 0,
               ) -> UploadOut:
    """Add images; each is processed in the background (status "pending" until done). All or nothing.
    Listed after those held, or with `batch`, by `position` among its files."""
    if len(expected) == 1:
        expected = expected * len(files)  # one label for the lot, as a folder of one sign's photos has
    if expected and len(expected) != len(files):
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"got {len(expected)} expected labels for {len(files)} files; send one for all of "
                            "them, one per file in their order (\"\" for none), or none")
    labels: list[str | None] = [*expected] if expected else [None] * len(files)
    uploads = [(*read_upload(f), label) for f, label in zip(files, labels)]
    return UploadOut(images=[summary(workspace, r) for r in workspace.add_images(uploads, batch, position)])


@router.get("/images", response_model=ImagesOut)
def list_images(workspace: WorkspaceDep) -> ImagesOut:
    progress = workspace.progress()
    return ImagesOut(version=progress["version"], running=progress["running"],
                     images=[summary(workspace, r) for r in workspace.images()])


@router.delete("/images", response_model=ImagesRemoved)
def delete_images(workspace: WorkspaceDep) -> ImagesRemoved:
    """Remove every image at once (the page's "remove all"; a DELETE per image takes a request each)."""
    return ImagesRemoved(removed=workspace.remove_images())


@router.get("/images/{image_id}", response_model=ImageDetail)
def get_image(record: RecordDep, workspace: WorkspaceDep) -> ImageDetail:
    return detail(workspace, record)


@router.patch("/images/{image_id}", response_model=ImageSummary, dependencies=[JSON_BODY])
def set_expected(body: ExpectedIn, record: RecordDep, workspace: WorkspaceDep) -> ImageSummary:
    """Set or clear the label the image should get."""
    return summary(workspace, workspace.set_expected(record.id, body.expected))


@router.delete("/images/{image_id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_image(record: RecordDep, workspace: WorkspaceDep) -> None:
    try:
        workspace.remove_image(record.id)
    except KeyError:  # deleted by a concurrent request
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"image {record.id!r} was already deleted") from None


@router.get("/images/{image_id}/file", response_class=FileResponse)
def get_image_file(record: RecordDep, workspace: WorkspaceDep) -> FileResponse:
    return FileResponse(workspace.image_path(record), media_type=record.media_type, filename=record.name,
                        content_disposition_type="inline")


@router.get("/images/{image_id}/stages/{stage}",
            responses={200: {"content": {"image/png": {}}, "description": "PNG figure"}})
def get_stage(record: RecordDep, stage: Literal[figures.STAGES], workspace: WorkspaceDep,  # type: ignore[valid-type]
              sign: Annotated[str | None, Query(description="matches/inliers: the sign to match against")] = None,
              ) -> Response:
    """A figure of one pipeline stage for the image's latest result (header X-Settings-Version)."""
    outcome = result_of(record)
    try:
        image = workspace.photo(record) if stage in figures.PHOTO_STAGES else record.gray
        img = figures.stage_figure(stage, image, outcome.recognition, workspace.library, sign)
    except figures.FigureError as exc:
        raise HTTPException(status.HTTP_404_NOT_FOUND, str(exc)) from None
    return Response(figures.png(img), media_type="image/png",
                    headers={"X-Settings-Version": str(outcome.settings_version)})


@router.post("/recognize", response_model=RecognitionOut, dependencies=[MULTIPART, ONE_FILE])
async def recognize_once(file: Annotated[UploadFile, File()], workspace: WorkspaceDep, queue: WorkQueueDep,
                         sign_maps: SignMapsDep) -> dict:
    """Recognise one image with the current settings, library and camera without keeping it: every sign in view,
    and while a sign map is held the camera in the map frame."""
    # The sync upload routes call read_upload directly; here, as in PUT /api/camera, the read goes
    # to a worker thread so that a large upload spooled to disk does not block the event loop.
    name, data = await run_in_threadpool(read_upload, file)
    recognitions = await queue.run(f"recognising {name}", lambda _: workspace.recognize_upload(data, name),
                                   limit_s=workspace.config.request_timeout_s)
    answer = recognitions[0]
    return {**answer.to_json(name), **in_view_json([SignSeen.of(r) for r in recognitions], sign_maps.held,
                                                   workspace.library, answer.camera)}
