"""Choosing settings: the threshold a sign's gray levels suggest, and sweeps of one setting over the
labelled images (app/tuning.py does both)."""

from __future__ import annotations

import dataclasses
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, status

from .. import tuning
from ..api_models import CalibrateIn, CalibrateOut, SweepOut
from ..responses import result_of
from .deps import JSON_BODY, JsonBodyRoute, WorkQueueDep, WorkspaceDep, find_record

router = APIRouter(tags=["tuning"], route_class=JsonBodyRoute)


@router.post("/calibrate/threshold", response_model=CalibrateOut, dependencies=[JSON_BODY])
async def calibrate_threshold(body: CalibrateIn, workspace: WorkspaceDep,
                              queue: WorkQueueDep) -> tuning.ThresholdSuggestion:
    """Measure the sign's white and suggest a threshold just below it (the paper: 0.8 measured, 0.75 set)."""
    record = find_record(workspace, body.image_id)
    normalization = workspace.settings.normalization

    def measure(_: object) -> tuning.ThresholdSuggestion:
        if body.rect is not None:
            inside, source = tuning.box_region(body.rect, record.width, record.height)
        else:
            inside, source = tuning.found_region(result_of(record).recognition, record.width, record.height,
                                                 record.name)
        return tuning.suggest_threshold(record.gray, normalization, inside, source)
    return await queue.run(f"measuring {record.name}", measure, limit_s=workspace.config.request_timeout_s)


@router.get("/sweep", response_model=SweepOut)
async def sweep(workspace: WorkspaceDep, queue: WorkQueueDep,
                param: Annotated[str, Query(description="a numeric setting: "
                                                        f"{', '.join(tuning.NUMERIC_SETTINGS)}")] = "threshold",
                lo: float = 0.3, hi: float = 0.9,
                steps: Annotated[int, Query(ge=2, le=tuning.MAX_SWEEP_STEPS)] = 13) -> SweepOut:
    """Re-run every labelled image for each of `steps` values of `param` from `lo` to `hi`."""
    values = tuning.values_to_sweep(workspace.settings, param, lo, hi, steps)
    labelled = [r for r in workspace.images() if r.expected is not None]
    if not labelled:
        raise HTTPException(status.HTTP_409_CONFLICT,
                            "no labelled images to sweep over: give images an expected label "
                            "(when uploading, or PATCH /api/images/{id})")
    runs = await queue.run(f"the sweep of {param} over {len(labelled)} images",
                           lambda stop: workspace.sweep(param, values, labelled, stop),
                           limit_s=workspace.config.request_timeout_s)
    tally = tuning.tally_sweep(values, [r.expected for r in labelled], runs,
                               integer=param in tuning.INTEGER_SETTINGS)
    return SweepOut(param=param, values=values, labelled=len(labelled), **dataclasses.asdict(tally))
