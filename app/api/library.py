"""The library of known signs: list, add (with the sign's image and size), fetch an image, delete."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, File, Form, HTTPException, UploadFile, status
from fastapi.responses import FileResponse

from ..api_models import SignOut
from ..uploads import read_upload
from .deps import MULTIPART, ONE_FILE, JsonBodyRoute, SignIdDep, SignMapsDep, WorkspaceDep, single

router = APIRouter(tags=["library"], route_class=JsonBodyRoute)


@router.get("/library", response_model=list[SignOut])
def get_library(workspace: WorkspaceDep) -> list[SignOut]:
    return [SignOut.of(s) for s in workspace.library.signs]


@router.get("/library/{sign_id}/image", response_class=FileResponse)
def get_sign_image(sign_id: SignIdDep, workspace: WorkspaceDep) -> FileResponse:
    return FileResponse(workspace.sign_path(sign_id))


@router.post("/library", response_model=SignOut, status_code=status.HTTP_201_CREATED,
             dependencies=[MULTIPART, ONE_FILE,
                           single("id", "width_m", "name", "text", "height_m", "kind", "min_text_correlation")])
def add_sign(file: Annotated[UploadFile, File(description="the sign, photographed flat or as artwork")],
             id: Annotated[str, Form(description="1-64 of a-z, 0-9, _ and -")],
             width_m: Annotated[float, Form(description="physical width, metres (0.02-10)")],
             workspace: WorkspaceDep,
             name: Annotated[str, Form()] = "", text: Annotated[str, Form()] = "",
             height_m: Annotated[float | None, Form(description="metres (0.02-10); default: from the image")] = None,
             kind: Annotated[str, Form(description='"plaque" or "picture"; empty: told from the image')] = "",
             min_text_correlation: Annotated[float | None, Form(
                 description="the text check's bar for this sign, 0 (no check) to 1; default: the settings'")] = None,
             ) -> SignOut:
    """Add a sign; 422 for a bad field (the message names it), 409 when its id is taken, or when its image
    cannot be told apart from a sign's already there (the message names it)."""
    _, data = read_upload(file)
    return SignOut.of(workspace.add_sign(id, data, name, text, width_m, height_m, kind=kind or None,
                                         min_text_correlation=min_text_correlation))


@router.delete("/library/{sign_id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_sign(sign_id: SignIdDep, workspace: WorkspaceDep, sign_maps: SignMapsDep) -> None:
    """Delete a sign; images whose result named it are re-run with the rest of the library. 409 while the sign
    map held places it: the map would name a sign the library lacks, and could not be loaded again."""
    held = sign_maps.held
    if held is not None and sign_id in held.sign_map.signs:
        raise HTTPException(status.HTTP_409_CONFLICT,
                            f"sign {sign_id!r} is in the sign map held ({held.source}): clear the map first (Sign map › "
                            "clear), or load one without it, then delete the sign")
    workspace.remove_sign(sign_id)
