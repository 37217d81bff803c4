"""The settings every image is run with: read, change, presets, export and import."""

from __future__ import annotations

import json
from typing import Annotated, Any

from fastapi import APIRouter, File, HTTPException, Query, Response, UploadFile, status

from signpose.pipeline.jsonfile import JsonError, parse_json
from signpose.pipeline.settings import PRESETS, Settings, SettingsError, file_settings, settings_schema

from ..api_models import SettingField, SettingsOut
from ..responses import settings_out
from ..uploads import read_upload
from .deps import JSON_BODY, MULTIPART, ONE_FILE, JsonBodyRoute, WorkspaceDep

router = APIRouter(tags=["settings"], route_class=JsonBodyRoute)


@router.get("/settings", response_model=SettingsOut)
def get_settings(workspace: WorkspaceDep,
                 version: Annotated[int | None, Query(ge=1, description="an earlier settings version")] = None,
                 ) -> SettingsOut:
    """The current settings, or those of an earlier `version` (to check what a result was computed under)."""
    if version is None:
        return settings_out(workspace)
    try:
        return SettingsOut(version=version, settings=workspace.settings_at(version))
    except KeyError:
        kept = workspace.settings_versions()
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"settings version {version} is not kept; "
                                                       f"versions {kept.start} to {kept.stop - 1} are") from None


@router.put("/settings", response_model=SettingsOut, dependencies=[JSON_BODY])
def put_settings(changes: dict[str, Any], workspace: WorkspaceDep) -> SettingsOut:
    """Change some or all settings; every image is re-run (debounced). 422 names the bad value."""
    workspace.update_settings(changes)
    return settings_out(workspace)


@router.get("/settings/schema", response_model=list[SettingField])
def get_schema() -> list[dict]:
    return settings_schema()


@router.get("/presets", response_model=dict[str, Settings])
def get_presets() -> dict[str, Settings]:
    return PRESETS


@router.post("/settings/preset/{name}", response_model=SettingsOut)
def apply_preset(name: str, workspace: WorkspaceDep) -> SettingsOut:
    if name not in PRESETS:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no preset {name!r}; choose from {', '.join(PRESETS)}")
    workspace.replace_settings(PRESETS[name])
    return settings_out(workspace)


@router.get("/settings/export",
            responses={200: {"content": {"application/json": {}}, "description": "signpose-settings.json"}})
def export_settings(workspace: WorkspaceDep) -> Response:
    return Response(json.dumps(workspace.settings.to_dict(), indent=2) + "\n", media_type="application/json",
                    headers={"Content-Disposition": 'attachment; filename="signpose-settings.json"'})


@router.post("/settings/import", response_model=SettingsOut, dependencies=[MULTIPART, ONE_FILE])
def import_settings(file: Annotated[UploadFile, File(description="settings JSON, full or partial")],
                    workspace: WorkspaceDep) -> SettingsOut:
    """Apply a settings file (as written by export or `--settings`) over the current settings."""
    name, data = read_upload(file)
    try:
        changes = file_settings(parse_json(data))
    except JsonError as exc:
        raise SettingsError(f"{name} is {exc}") from None
    workspace.update_settings(changes)
    return settings_out(workspace)
