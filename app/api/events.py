"""What the server is doing: `/api/health`, asked for, and `/api/events`, the stream of every change
as it happens (server-sent events)."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterable

from fastapi import APIRouter, Request
from fastapi.sse import EventSourceResponse, ServerSentEvent

from ..api_models import Health
from ..events import Event
from .deps import JsonBodyRoute, WorkspaceDep

router = APIRouter(tags=["server"], route_class=JsonBodyRoute)


@router.get("/health", response_model=Health)
async def health(request: Request, workspace: WorkspaceDep) -> Health:
    """On the event loop and taking no lock: it answers while every worker thread is busy."""
    images, held = workspace.held_now()
    return Health(version=request.app.version, images=images, busy=workspace.busy,
                  memory_held_bytes=held, memory_limit_bytes=workspace.config.max_memory_bytes)


@router.get("/events", response_class=EventSourceResponse)
async def events(workspace: WorkspaceDep) -> AsyncIterable[ServerSentEvent]:
    """Server-sent events: `settings`, `results`, `library`, `camera`, `images`, `calibration` (payloads in
    the contract).

    Starts with the current `settings` and `results`. Events of one kind that arrive faster
    than they are sent collapse into the newest.
    """
    loop = asyncio.get_running_loop()
    latest: dict[str, dict] = {}
    wake = asyncio.Event()

    def store(event: Event) -> None:
        latest[event.kind] = event.payload
        wake.set()

    def hand_over(event: Event) -> None:
        """Called in the thread that published `event`: the event loop stores it."""
        loop.call_soon_threadsafe(store, event)

    unsubscribe = workspace.subscribe(hand_over)
    try:
        snap = workspace.snapshot
        yield ServerSentEvent(event="settings",
                              data={"version": snap.settings_version, "settings": snap.settings.to_dict()})
        yield ServerSentEvent(event="results", data=workspace.progress())
        while True:
            await wake.wait()
            wake.clear()
            pending = dict(latest)
            latest.clear()
            for kind, payload in pending.items():
                yield ServerSentEvent(event=kind, data=payload)
    finally:
        unsubscribe()
