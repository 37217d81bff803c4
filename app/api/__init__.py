"""signpose's JSON API under /api: one router per resource, composed here in the order their paths
are matched and listed in the OpenAPI document. What the routes share is in deps.py; the answers are
shaped by app/responses.py, uploads checked by app/uploads.py; app/server.py's `create_app` mounts
`router` with the exception handlers that turn domain errors into 4xx."""

from __future__ import annotations

from fastapi import APIRouter

from . import calibration, camera, events, flights, images, library, map, scene, settings, tuning

router = APIRouter(prefix="/api")
for resource in (events, settings, library, images, flights, map, tuning, camera, calibration, scene):
    router.include_router(resource.router)
