"""`signpose serve`: the page, the JSON API, OpenAPI docs and the viser client on one port.

`create_app` builds the FastAPI app around one `Workspace` (docs/web-contract.md lists every
endpoint): the API's routers (app/api/), the middleware, the exception handlers, the page and the
viser relay; `bind` and `serve` run it with uvicorn. Routes are thin: they validate, call the
workspace or the pipeline off the event loop (plain `def` routes run in a thread pool, heavy work
in the queue of app/heavy.py, 503 "busy" when it is full) and shape the answer
(app/responses.py). Domain errors become 4xx with the pipeline's own message: SettingsError,
CameraError, LibraryError, ImageError, CalibrationError, PipelineError, TuningError, FlightError and
MapError 422, ImageTooLarge, FlightTooLarge and oversized bodies 413 (app/uploads.py), Conflict and
MapBuildError (no map from the photos held) 409, unknown
ids 404, pipeline work past the request time limit 503; requests that fail validation 422, as one `where: what` line that
never echoes the input. app/security.py guards access and sets security headers. The camera
calibration session (app/calibration.py), the flights (app/flights.py) and the sign map
(app/sign_maps.py) sit beside the Workspace
and reach the routes through their own dependencies.
"""

from __future__ import annotations

import contextlib
import io
import logging
import socket
import tomllib
from collections.abc import AsyncIterator, Awaitable, Callable
from importlib import metadata
from pathlib import Path

from fastapi import FastAPI, Request, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline
from starlette.concurrency import run_in_threadpool
from starlette.routing import Match, Mount

from signpose.pipeline import shipped_folder
from signpose.pipeline.calibrate import CalibrationError
from signpose.pipeline.camera import CameraError, load_camera
from signpose.pipeline.image import ImageError
from signpose.pipeline.library import LibraryError
from signpose.pipeline.recognize import PipelineError
from signpose.pipeline.settings import SettingsError
from signpose.pipeline.map_build import MapBuildError
from signpose.pipeline.sign_map import MapError

from . import api
from .calibration import CalibrationSession
from .flights import FlightError, Flights, FlightTooLarge
from .heavy import WorkQueue
from .image_store import Conflict, ImageTooLarge
from .scene import attach as attach_scene
from .security import DOCS_ASSETS, AccessGuard, SecurityHeaders
from .sign_maps import open_sign_maps
from .tuning import TuningError
from .uploads import UploadLimit
from .viser_proxy import PrivateViser, mount_viser
from .workspace import SAMPLE_FLIGHT, Workspace, WorkspaceConfig

log = logging.getLogger(__name__)

STATIC_DIR = shipped_folder(Path(__file__).resolve().parent, "static")
BACKLOG = 2048  # uvicorn's default


def package_version() -> str:
    """The installed signpose version, else (a source checkout) the one in pyproject.toml."""
    try:
        return metadata.version("signpose")
    except metadata.PackageNotFoundError:
        pyproject = Path(__file__).resolve().parent.parent / "pyproject.toml"
        return tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]["version"]


def _error_handler(code: int) -> Callable[[Request, Exception], Awaitable[JSONResponse]]:
    """An exception handler answering `code` with the exception's message: domain errors say what to do."""
    async def handler(request: Request, exc: Exception) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=code)
    return handler


def _problem(error: dict) -> str:
    """One pydantic validation error as `where: what`, without the input."""
    what = "unknown key, which this request does not take" if error["type"] == "extra_forbidden" else error["msg"]
    return f"{'.'.join(map(str, error['loc']))}: {what}"


async def _validation_error_handler(request: Request, exc: Exception) -> JSONResponse:
    """422 `{"detail": "<every problem, one line>"}` like every other error. FastAPI's default
    answers a list that echoes the input, and cannot encode it when it holds NaN or Infinity (a 500).
    Registered for RequestValidationError only; Starlette types every handler over Exception."""
    assert isinstance(exc, RequestValidationError)
    return JSONResponse({"detail": "; ".join(map(_problem, exc.errors()))},
                        status_code=status.HTTP_422_UNPROCESSABLE_CONTENT)


API_METHODS = ["GET", "POST", "PUT", "PATCH", "DELETE"]


def _unknown_api_route(app: FastAPI) -> Callable[[Request], Awaitable[JSONResponse]]:
    """The answer to an /api request no route takes: 405 naming the methods of a route of that path, else 404
    naming /docs. Both fell through to the page's static files, whose bare 404 "Not Found" said neither."""
    async def answer(request: Request) -> JSONResponse:
        path = request.url.path
        allowed = [method for method in API_METHODS if any(
            getattr(route, "endpoint", None) is not answer and not isinstance(route, Mount)
            and route.matches({**request.scope, "method": method})[0] == Match.FULL for route in app.router.routes)]
        if allowed:
            return JSONResponse({"detail": f"{request.method} {path}: this route takes {', '.join(allowed)}"},
                                status_code=status.HTTP_405_METHOD_NOT_ALLOWED, headers={"Allow": ", ".join(allowed)})
        return JSONResponse({"detail": f"no API route {path}: every route is listed at /docs"},
                            status_code=status.HTTP_404_NOT_FOUND)
    return answer


def add_sample_flight(flights: Flights, folder: Path = SAMPLE_FLIGHT) -> None:
    """The sample flight (sample_images/flights/corridor: its video and camera file), among the flights;
    logged and left out when it cannot be read."""
    try:
        camera = load_camera(folder / "camera.yaml")
        with (folder / "flight.mp4").open("rb") as video:
            flights.add(f"{folder.name}.mp4", video, camera=camera)
    except (OSError, ValueError) as exc:
        log.warning("sample flight %s not loaded: %s", folder, exc)


def create_app(source: Workspace | WorkspaceConfig, token: str | None = None) -> FastAPI:
    """The signpose app around `source`: a Workspace the caller owns and closes, or a config to
    build one from (then the app closes it at shutdown). The viser server starts with the app.

    With `token`, every request and websocket must carry it (app/security.py); without, only
    requests addressed to a loopback host are answered.
    """
    workspace = source if isinstance(source, Workspace) else Workspace.open(source)
    owned = workspace is not source
    try:
        sign_maps = open_sign_maps(workspace)
    except MapError:
        if owned:
            workspace.close()
        raise

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # viser prints its private address unconditionally; people should only see ours.
        with contextlib.redirect_stdout(io.StringIO()):
            private = PrivateViser.start()
        app.state.viser_socket = private.socket_path
        scene = app.state.scene = attach_scene(private.server, workspace, flights, sign_maps)
        try:
            yield
        finally:
            scene.close()
            private.stop()
            stop_flights()
            await run_in_threadpool(flights.close)
            if owned:
                await run_in_threadpool(workspace.close)

    # Swagger UI and ReDoc from files installed with the package: a competition venue may have no internet.
    app = FastAPIOffline(title="signpose", version=package_version(), lifespan=lifespan, static_url=DOCS_ASSETS,
                         summary="Recognise known planar signs and recover the camera pose; tune every step.")
    app.state.workspace = workspace
    app.state.scene = None   # until the lifespan attaches it
    app.state.sign_maps = sign_maps
    app.state.calibration = CalibrationSession(workspace.config.max_pixels,
                                               publish=lambda payload: workspace.publish("calibration", payload))
    app.state.work_queue = WorkQueue(workers=workspace.config.workers)
    config = workspace.config
    flights = app.state.flights = Flights(snapshot=lambda: workspace.snapshot, publish=workspace.publish,
                                          max_flights=config.max_flights, max_frames=config.max_flight_frames,
                                          max_bytes=config.max_flight_upload_bytes, max_pixels=config.max_pixels)
    stop_flights = workspace.subscribe(flights.on_event)
    if workspace.shows_samples:
        add_sample_flight(flights)
    # The last added runs first: headers on every answer, then access, then the body limit.
    app.add_middleware(UploadLimit, max_bytes=config.max_upload_bytes,
                       routes={"/api/flights": (config.max_flight_upload_bytes, "--max-flight-mb")})
    app.add_middleware(AccessGuard, token=token)
    app.add_middleware(SecurityHeaders)
    for error, code in ((SettingsError, 422), (CameraError, 422), (LibraryError, 422), (ImageError, 422),
                        (PipelineError, 422), (CalibrationError, 422), (TuningError, 422), (FlightError, 422),
                        (MapError, 422), (ImageTooLarge, 413), (FlightTooLarge, 413), (Conflict, 409),
                        (MapBuildError, 409)):
        app.add_exception_handler(error, _error_handler(code))
    app.add_exception_handler(RequestValidationError, _validation_error_handler)
    app.include_router(api.router)
    app.router.add_route("/api/{path:path}", _unknown_api_route(app), methods=API_METHODS)
    mount_viser(app)
    app.mount("/", StaticFiles(directory=STATIC_DIR, html=True, check_dir=False), name="static")
    return app


def bind(host: str, port: int) -> socket.socket:
    """A listening socket on (host, port); OSError with the reason when it is taken or not ours.

    Listening from here on, so the URL can be printed at once: connections made before the
    server runs wait in the backlog.
    """
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
        sock.listen(BACKLOG)
    except OSError:
        sock.close()
        raise
    sock.set_inheritable(True)
    return sock


# Seconds an idle connection is kept open: longer than clients keep one for reuse (httpx 5 s,
# uvicorn's own default too), since at equal times a request sent as the server closed it was reset.
KEEP_ALIVE_S = 30


def serve(app: FastAPI, sock: socket.socket) -> None:
    """Run `app` on the bound `sock` with one uvicorn worker until Ctrl+C or SIGTERM."""
    import uvicorn

    config = uvicorn.Config(app, workers=1, log_level="warning", timeout_graceful_shutdown=2,
                            timeout_keep_alive=KEEP_ALIVE_S)
    try:
        uvicorn.Server(config).run(sockets=[sock])
    except KeyboardInterrupt:  # uvicorn re-raises the Ctrl+C it handled; the shutdown is already done
        pass
