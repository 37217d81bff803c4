"""Flights: a video or a ROS bag uploaded, tracked in the background (app/flights.py), its frames'
results and images, the frame the page shows (the 3D scene's current camera), exports as MCAP, CSV or
JSON lines, and its removal."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Depends, File, Form, HTTPException, Response, UploadFile, status
from fastapi.responses import FileResponse
from starlette.background import BackgroundTask
from starlette.concurrency import run_in_threadpool

from signpose.pipeline.camera import read_camera

from ..api_models import FlightCursorIn, FlightFramesOut, FlightOut, FlightsOut
from ..flights import Flight
from ..uploads import read_upload, single_values, the_file
from .deps import JSON_BODY, MULTIPART, FlightsDep, JsonBodyRoute, WorkQueueDep, WorkspaceDep, form_check

router = APIRouter(tags=["flights"], route_class=JsonBodyRoute)

EXPORTS = {"mcap": (".mcap", "application/octet-stream"), "csv": (".csv", "text/csv"),
           "jsonl": (".jsonl", "application/x-ndjson")}


def get_flight(flight_id: str, flights: FlightsDep) -> Flight:
    try:
        return flights.get(flight_id)
    except KeyError:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"no flight with id {flight_id!r}; GET /api/flights lists them") from None


FlightDep = Annotated[Flight, Depends(get_flight)]


def frame_index(flight: Flight, index: int) -> int:
    """`index` when the flight's last run has that frame; 404 saying which it has, or 409 before the first run ends."""
    count = len(flight.records)
    if count == 0:
        raise HTTPException(status.HTTP_409_CONFLICT, f"flight {flight.name} has no tracked frames yet "
                            f"({flight.status}): wait for its processing to end")
    if not 0 <= index < count:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"flight {flight.name} has frames 0 to {count - 1}, not {index}")
    return index


# The camera file beside a flight is optional, so not checked by `the_file`; one sent twice is refused all the same.
ONE_CAMERA = form_check(lambda form: single_values(form, ("camera", "topic")))


@router.post("/flights", response_model=FlightOut, status_code=status.HTTP_201_CREATED,
             dependencies=[MULTIPART, form_check(the_file), ONE_CAMERA])
async def add_flight(file: Annotated[UploadFile, File(description="a video, a ROS bag (.mcap, .db3, .bag) or a "
                                                                  "rosbag2 folder as a .zip")],
                     flights: FlightsDep, workspace: WorkspaceDep,
                     camera: Annotated[UploadFile | None, File(description="the camera file of the camera that "
                                                                             "filmed it (optional)")] = None,
                     topic: Annotated[str, Form(max_length=256, description="a bag's image topic (default: its "
                                                                             "only one)")] = "") -> FlightOut:
    """Add a flight: checked (it opens, its first frame decodes, its camera fits it), then tracked in the
    background (status "queued", then "processing" with `done` of `total`; `flights` events)."""
    intrinsics = None
    if camera is not None:
        name, data = await run_in_threadpool(read_upload, camera, "camera")
        intrinsics = await run_in_threadpool(read_camera, data, name)
    flight = await run_in_threadpool(flights.add, file.filename or "flight", file.file, camera=intrinsics,
                                     topic=topic or None)
    return FlightOut(**flight.summary())


@router.get("/flights", response_model=FlightsOut)
def list_flights(flights: FlightsDep) -> FlightsOut:
    return FlightsOut(flights=[FlightOut(**f.summary()) for f in flights.held()])


@router.get("/flights/{flight_id}", response_model=FlightOut)
def get_flight_summary(flight: FlightDep) -> FlightOut:
    return FlightOut(**flight.summary())


@router.delete("/flights/{flight_id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_flight(flight: FlightDep, flights: FlightsDep) -> None:
    try:
        flights.remove(flight.id)
    except KeyError:  # deleted by a concurrent request
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"flight {flight.name} was already deleted") from None


@router.get("/flights/{flight_id}/frames", response_model=FlightFramesOut)
def get_flight_frames(flight: FlightDep) -> FlightFramesOut:
    """Every frame's result of the last complete run (empty before the first ends)."""
    return FlightFramesOut(id=flight.id, result_version=flight.result_version, frames=flight.records)


@router.get("/flights/{flight_id}/frames/{index}")
def get_flight_frame(flight: FlightDep, index: int) -> dict:
    """One frame's line of `signpose track --json`."""
    return flight.records[frame_index(flight, index)]


@router.get("/flights/{flight_id}/frames/{index}/image",
            responses={200: {"content": {"image/jpeg": {}}, "description": "the frame as JPEG"}})
def get_flight_frame_image(flight: FlightDep, index: int) -> Response:
    """The frame as the tracker read it (JPEG; frames wider than 1280 px scaled down)."""
    return Response(flight.jpegs[frame_index(flight, index)], media_type="image/jpeg",
                    headers={"Cache-Control": "private, max-age=3600"})


@router.put("/flights/{flight_id}/cursor", status_code=status.HTTP_204_NO_CONTENT, dependencies=[JSON_BODY])
def put_flight_cursor(body: FlightCursorIn, flight: FlightDep, flights: FlightsDep) -> None:
    """The frame the page shows: the 3D scene's current camera of the flight follows it."""
    try:
        flights.set_cursor(flight.id, frame_index(flight, body.frame))
    except (KeyError, IndexError):  # deleted or re-run meanwhile
        raise HTTPException(status.HTTP_409_CONFLICT, f"flight {flight.name} changed meanwhile; "
                            "GET /api/flights/{id} again") from None


@router.get("/flights/{flight_id}/export", response_class=FileResponse)
async def export_flight(flight: FlightDep, flights: FlightsDep, queue: WorkQueueDep, workspace: WorkspaceDep,
                        format: Literal["mcap", "csv", "jsonl"]) -> FileResponse:  # noqa: A002 (the query's name)
    """The flight's poses as `signpose track -o` writes them: a ROS 2 MCAP (with the frames, for a video),
    CSV or JSON lines."""
    frame_index(flight, 0)
    suffix, media_type = EXPORTS[format]
    path = await queue.run(f"exporting {flight.name}", lambda _: flights.export(flight, suffix),
                           limit_s=workspace.config.request_timeout_s)
    stem = flight.name.rsplit(".", 1)[0] or "flight"
    return FileResponse(path, media_type=media_type, filename=f"{stem}{suffix}",
                        background=BackgroundTask(path.unlink, missing_ok=True))
