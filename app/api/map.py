"""The sign map held (app/sign_maps.py): see it, load a map file, build one from the photos and flights
held (as `signpose map build` does), download it as YAML, clear it."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, File, HTTPException, Response, UploadFile, status
from starlette.concurrency import run_in_threadpool

from signpose.pipeline.sign_map import read_sign_map

from ..api_models import MapBuildIn, MapOut
from ..responses import map_out
from ..sign_maps import build_from_held
from ..uploads import read_upload
from .deps import (MULTIPART, ONE_FILE, OPTIONAL_JSON_BODY, FlightsDep, JsonBodyRoute, SignMapsDep, WorkQueueDep,
                   WorkspaceDep)

router = APIRouter(tags=["map"], route_class=JsonBodyRoute)

NO_MAP = "no sign map is held: load a map file (PUT /api/map) or build one from the photos (POST /api/map/build)"


@router.get("/map", response_model=MapOut | None)
def get_map(sign_maps: SignMapsDep) -> MapOut | None:
    """The map held, each sign's pose and 1-sigma; null when there is none."""
    held = sign_maps.held
    return None if held is None else map_out(held)


@router.put("/map", response_model=MapOut, dependencies=[MULTIPART, ONE_FILE])
async def load_map(file: Annotated[UploadFile, File(description="a map file, YAML or JSON (docs/map.md)")],
                   sign_maps: SignMapsDep, workspace: WorkspaceDep) -> MapOut:
    """Hold the map file uploaded, its signs among the library's; 422 naming the field for a bad
    file, the map held before kept."""
    name, data = await run_in_threadpool(read_upload, file, "map")
    sign_map = await run_in_threadpool(read_sign_map, data, name, workspace.library.ids)
    return map_out(sign_maps.hold_file(sign_map, name))


@router.post("/map/build", response_model=MapOut, dependencies=[OPTIONAL_JSON_BODY])
async def build_map_from_held(sign_maps: SignMapsDep, workspace: WorkspaceDep, flights: FlightsDep,
                              queue: WorkQueueDep, body: MapBuildIn | None = None) -> MapOut:
    """Build the map from every sign in the photos held and the frames of the flights tracked, with
    `anchor`'s frame as the map frame (default: the first sign seen), and hold it. 409 saying why
    when no map can be built (no sign seen, the anchor not seen, signs in groups no photo links,
    named), the map held before kept."""
    anchor = (body or MapBuildIn()).anchor
    if anchor is not None and anchor not in workspace.library.ids:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"anchor {anchor!r} is not a sign of the library, which has "
                            f"{', '.join(workspace.library.ids)}")
    images = len(workspace.images())
    build, source, names, warnings = await queue.run(
        f"the map build from {images} photo(s)", lambda stop: build_from_held(workspace, flights, anchor, stop),
        limit_s=workspace.config.request_timeout_s)
    return map_out(sign_maps.hold_build(build, source, names, warnings))


@router.get("/map/file", responses={200: {"content": {"application/x-yaml": {}}, "description": "the map file"}})
def get_map_file(sign_maps: SignMapsDep) -> Response:
    """The map held as a map file (YAML; a built map's signs with the build's report in comments),
    which PUT /api/map and `--map` read back."""
    held = sign_maps.held
    if held is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, NO_MAP)
    return Response(held.yaml(), media_type="application/x-yaml",
                    headers={"Content-Disposition": 'attachment; filename="map.yaml"'})


@router.delete("/map", status_code=status.HTTP_204_NO_CONTENT)
def clear_map(sign_maps: SignMapsDep) -> None:
    """Forget the map held (the 3D scene's map world empties)."""
    sign_maps.clear()
