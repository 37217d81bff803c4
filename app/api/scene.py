"""The 3D scene's viewers (app/scene.py draws the scene; viser's page reaches it at /viser/)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, status

from ..api_models import CanvasScaleIn
from .deps import JSON_BODY, JsonBodyRoute, SceneDep

router = APIRouter(tags=["scene"], route_class=JsonBodyRoute)


@router.put("/scene/canvas", status_code=status.HTTP_204_NO_CONTENT, dependencies=[JSON_BODY])
def put_scene_canvas(canvas: CanvasScaleIn, scene: SceneDep, viewer: Annotated[int, Query(
        ge=0, description="the viser client whose canvas this is: viser's page is told its id")]) -> None:
    """How many device px a 3D viewer's canvas (of this size as viser reports it) has to the CSS px:
    viser's client reports its canvas in device px but draws the camera labels at a size in CSS px,
    and the scene lays them out in CSS px. viser's page sends this (static/viser-canvas.js)."""
    if scene is not None:
        scene.set_canvas_width(viewer, canvas.width / canvas.px_per_css_px)
