"""`signpose serve`: the page, the JSON API, OpenAPI docs and the viser client on one port.

`create_app` builds the FastAPI app around one `Workspace` (docs/web-contract.md lists every
endpoint). Routes are thin: they validate, call the workspace or the pipeline off the event
loop (plain `def` routes run in a thread pool) and shape the answer. Domain errors become 4xx
with the pipeline's own message: SettingsError, CameraError, LibraryError, ImageError,
CalibrationError and PipelineError 422, ImageTooLarge and oversized bodies 413, Conflict 409,
unknown ids 404, pipeline work past the request time limit 503; requests that fail validation 422,
as one `where: what` line that never echoes the input. app/security.py guards access
and sets security headers. The camera calibration session (app/calibration.py) sits beside the
Workspace and reaches the routes through its own dependency.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import io
import json
import math
import socket
import tempfile
import threading
import tomllib
from collections.abc import AsyncIterable, Awaitable, Callable
from importlib import metadata
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

import anyio
import viser
from fastapi import APIRouter, Depends, FastAPI, File, Form, HTTPException, Query, Request, Response, UploadFile, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse
from fastapi.routing import APIRoute
from fastapi.sse import EventSourceResponse, ServerSentEvent
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import FormData, Headers, UploadFile as FormFile
from starlette.types import ASGIApp, Receive, Scope, Send

from signpose.pipeline import shipped_folder
from signpose.pipeline.calibrate import MAX_SQUARE_M, MIN_VIEWS, Calibration, CalibrationError
from signpose.pipeline.camera import Camera, CameraError, camera_from_json, load_camera, ros_camera_yaml
from signpose.pipeline.exif import turned_camera
from signpose.pipeline.image import ImageError
from signpose.pipeline.jsonfile import JsonError, parse_json
from signpose.pipeline.library import ID_PATTERN, LibraryError
from signpose.pipeline.settings import (PRESETS, Settings, SettingsError, check_setting, file_settings,
                               settings_schema)

from . import figures, tuning
from .api_models import (
    AssumedFovIn, AttemptOut, BoardSearchOut, BoardSpec, CalibrateIn, CalibrateOut, CalibrationAdded, CalibrationOut,
    CalibrationResult,
    CalibrationRunIn, CalibrationView, CameraIntrinsics, CameraModel, CameraOut, CanvasScaleIn, ExpectedIn, Health,
    ImageDetail, ImagesOut, ImagesRemoved, ImageSummary, RecognitionOut, SettingField, SettingsOut, SignOut, SweepOut,
    UploadOut,
)
from .calibration import (PREVIEW_MAX_SIDE, CalibrationSession, CalibrationState, calibrated_camera,
                          page_outlier_advice)
from .security import DOCS_ASSETS, AccessGuard, SecurityHeaders
from .viser_proxy import PrivateViser, mount_viser
from .workspace import (
    IMAGE_ID, Conflict, ImageRecord, ImageTooLarge, Outcome, PipelineError, Workspace, WorkspaceConfig, display_name,
    is_correct, status_of,
)

STATIC_DIR = shipped_folder(Path(__file__).resolve().parent, "static")
CAMERA_SUFFIXES = (".yaml", ".yml", ".json", ".xml")
MAX_SWEEP_STEPS = 101
BACKLOG = 2048  # uvicorn's default
T = TypeVar("T")


def package_version() -> str:
    """The installed signpose version, else (a source checkout) the one in pyproject.toml."""
    try:
        return metadata.version("signpose")
    except metadata.PackageNotFoundError:
        pyproject = Path(__file__).resolve().parent.parent / "pyproject.toml"
        return tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]["version"]


# ---------------------------------------------------------------- request size limit

class UploadLimit:
    """Refuse request bodies over `max_bytes` with 413: at once when Content-Length says so,
    else as soon as the bytes received pass the limit, so nothing larger is ever buffered."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    def message(self, size: int | None) -> str:
        """Why a body of `size` bytes (None: not declared) is refused, and what to do: the page sends one
        file per request, so a single large photo can only pass with the limit raised where it is set."""
        size_text = f"{size / 1e6:.1f} MB, " if size is not None else ""
        enough = f" {math.ceil(size / 1e6)}" if size is not None else ""
        return (f"the upload is {size_text}more than this server's limit of {self.max_bytes / 1e6:.1f} MB per request: "
                f"send fewer or smaller files per request, or start the server with a higher limit "
                f"(signpose serve --max-upload-mb{enough})")

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = Headers(scope=scope).get("content-length", "")
        if declared.isdigit() and int(declared) > self.max_bytes:
            await JSONResponse({"detail": self.message(int(declared))}, status.HTTP_413_CONTENT_TOO_LARGE)(
                scope, receive, send)
            return
        received = 0

        async def counting_receive():
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    # Raised inside the app's body parsing; FastAPI turns it into the response.
                    raise HTTPException(status.HTTP_413_CONTENT_TOO_LARGE, self.message(None))
            return message

        await self.app(scope, counting_receive, send)


# ---------------------------------------------------------------- dependencies


def get_workspace(request: Request) -> Workspace:
    return request.app.state.workspace


WorkspaceDep = Annotated[Workspace, Depends(get_workspace)]


def find_record(workspace: Workspace, image_id: str) -> ImageRecord:
    try:
        if IMAGE_ID.match(image_id):
            return workspace.get(image_id)
    except KeyError:
        pass
    raise HTTPException(status.HTTP_404_NOT_FOUND, f"no image with id {image_id!r}; GET /api/images lists them")


def get_record(image_id: str, workspace: WorkspaceDep) -> ImageRecord:
    return find_record(workspace, image_id)


RecordDep = Annotated[ImageRecord, Depends(get_record)]


def get_sign_id(sign_id: str, workspace: WorkspaceDep) -> str:
    if not ID_PATTERN.match(sign_id) or sign_id not in workspace.library.ids:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"no sign {sign_id!r} in the library; known: {', '.join(workspace.library.ids)}")
    return sign_id


SignIdDep = Annotated[str, Depends(get_sign_id)]


def get_calibration(request: Request) -> CalibrationSession:
    return request.app.state.calibration


CalibrationDep = Annotated[CalibrationSession, Depends(get_calibration)]


class BodyType:
    """A dependency: 415 unless the request body is `media_type`. Without it FastAPI would only
    report the fields of a body it did not parse as missing, or the body as not a dictionary.
    `optional`: no body at all (`curl -X POST URL`) is fine too, whatever Content-Type is named."""

    def __init__(self, media_type: str, how: str, optional: bool = False) -> None:
        self.media_type = media_type
        self.how = how
        self.optional = optional

    def __call__(self, request: Request) -> None:
        if self.optional and "transfer-encoding" not in request.headers and \
                request.headers.get("content-length", "0") == "0":
            return
        content_type = request.headers.get("content-type", "")
        if content_type.split(";", 1)[0].strip().lower() != self.media_type:
            raise HTTPException(status.HTTP_415_UNSUPPORTED_MEDIA_TYPE,
                                f"send {self.how}; got Content-Type {content_type or 'none'!r}")


MULTIPART = Depends(BodyType("multipart/form-data", "the file(s) as multipart/form-data, as a browser form or "
                                                    "curl -F does"))
JSON_BODY = Depends(BodyType("application/json", "a JSON body with the header Content-Type: application/json"))
OPTIONAL_JSON_BODY = Depends(BodyType("application/json", "no body, or a JSON body with the header "
                                                          "Content-Type: application/json", optional=True))


def uploads(form: FormData, field: str) -> list[FormFile]:
    """The files in the multipart `field`; 422 naming the part that is not a file. A part sent
    without a file name (a text field, or a file whose name was left empty) is text to multipart,
    and FastAPI would refuse it as "Expected UploadFile, received: <class 'str'>"."""
    values = form.getlist(field)
    for i, value in enumerate(values, 1):
        if not isinstance(value, FormFile):
            which = f"part {i} of {len(values)} in" if len(values) > 1 else "the part in"
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"{which} the multipart field {field!r} is not a file: it has no file name, so it "
                                f"arrived as text; send each file with its name, as a browser form or "
                                f"curl -F '{field}=@<path>' does")
    return values


def the_file(form: FormData) -> FormFile:
    """The one upload in the multipart field 'file'; 422 when it is missing, not a file, or there are
    several: a form field read as one value is the last of them, and the others would be dropped unseen."""
    files = uploads(form, "file")
    if len(files) > 1:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"got {len(files)} files in the multipart field 'file'; this takes exactly one, "
                            "so send one request per file")
    if not files:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, "send the file in the multipart field 'file'")
    return files[0]


def form_check(check: Callable[[FormData], object]) -> Any:
    """A dependency of multipart routes that runs `check` (raising HTTPException) on the form FastAPI
    has already parsed (and will close), before FastAPI reads its fields its own way."""
    async def dependency(request: Request) -> None:
        check(await request.form())
    return Depends(dependency)


def single_values(form: FormData, fields: tuple[str, ...]) -> None:
    """422 when one of the text `fields` is sent several times, as `the_file` refuses several files:
    a route reading it as one value would take the last silently."""
    for field in fields:
        if (count := len(form.getlist(field))) > 1:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"got {count} values in the multipart field {field!r}; it takes one, so send it once")


ONE_FILE = form_check(the_file)  # routes whose `file` parameter takes one upload
FILES = form_check(lambda form: uploads(form, "files"))  # routes whose `files` parameter takes uploads


def single(*fields: str) -> Any:
    """A dependency of the multipart routes that read each of the text `fields` as one value (`single_values`)."""
    return form_check(lambda form: single_values(form, fields))


# The multipart fields of the routes that take a batch of uploads a request each (workspace.Slot).
Batch = Annotated[str, Form(max_length=64, description="a name the client gives a batch of files it sends a "
                                                       "request each, several at once: they are listed by "
                                                       "`position`, whatever order they land in")]
Position = Annotated[int, Form(ge=0, description="the place in `batch` of this request's first file; "
                                                "only with `batch`")]


def in_order(form: FormData) -> None:
    """422 unless `batch` and `position` are sent once each (`single_values`) and `position` with a `batch`:
    alone it would be ignored, and the files listed in the order they land rather than the one meant."""
    single_values(form, ("batch", "position"))
    if "position" in form and not form.get("batch"):
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            "'position' is the place of this request's files within a 'batch' and needs one: send "
                            "'batch' too, the same name in every request of the batch, or leave 'position' out")


IN_ORDER = form_check(in_order)


def result_of(record: ImageRecord) -> Outcome:
    """The image's latest outcome that has a result (possibly from older settings); 409 while there is none.

    Read once: the result and its settings version must come from the same run.
    """
    outcome = record.outcome
    if outcome.recognition is not None:
        return outcome
    if outcome.error is not None:
        raise HTTPException(status.HTTP_409_CONFLICT, f"{record.name}: {outcome.error}")
    raise HTTPException(status.HTTP_409_CONFLICT, f"{record.name} is still being processed; try again in a moment")


async def within_time_limit(workspace: Workspace, what: str, work: Callable[[threading.Event], T]) -> T:
    """`work(stop)` in a worker thread; 503 once it runs past the request time limit.

    A stuck pipeline call cannot be killed: the request is answered, the thread abandoned, and
    `stop` set so that work able to end early (a sweep between runs) does.
    """
    limit = workspace.config.request_timeout_s
    stop = threading.Event()
    try:
        with anyio.fail_after(limit):
            return await anyio.to_thread.run_sync(work, stop, abandon_on_cancel=True)
    except TimeoutError:
        stop.set()
        raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE,
                            f"{what} took longer than the {limit:g} s limit (signpose serve --request-timeout); "
                            "try fewer images or steps, or lighter settings") from None


# ---------------------------------------------------------------- shaping


def summary(workspace: Workspace, record: ImageRecord, outcome: Outcome | None = None) -> ImageSummary:
    """The image's summary from `outcome` (default: its latest). A sign the plaque fallback found
    has no feature inliers or margin (null, as the CLI's table shows '-'), but its correlation."""
    outcome = record.outcome if outcome is None else outcome
    rec = outcome.recognition
    by_plaque = bool(rec and rec.by_plaque)
    return ImageSummary(
        id=record.id, name=record.name, expected=record.expected,
        label=rec.label if rec else None, recognized=bool(rec and rec.recognized),
        inliers=None if by_plaque else rec.best.n_inliers if rec and rec.best else 0,
        margin=None if by_plaque else rec.margin if rec else 0,
        by_plaque=by_plaque, plaque_correlation=round(rec.plaque.correlation, 4) if by_plaque else None,
        status=status_of(record.expected, outcome, workspace.snapshot.generation),
        settings_version=outcome.settings_version, result_version=outcome.generation,
        width=record.width, height=record.height, error=outcome.error,
    )


def camera_kind(camera: Camera) -> str:
    """Where intrinsics came from, for people (CameraIntrinsics.kind), from their `source`."""
    # the pipeline's own tests, so the two cannot disagree
    if camera.is_assumed:
        return "assumed"
    if camera.is_exif:
        return "exif"
    for prefix, kind in (("calibrat", "calibration"), ("json", "typed")):
        if camera.source.startswith(prefix):
            return kind
    return "file"  # file:<path>, upload:<name>, or a camera made by a script


def intrinsics(camera: Camera | None) -> CameraIntrinsics | None:
    return None if camera is None else CameraIntrinsics(**camera.to_json(), kind=camera_kind(camera))


def misfit_warnings(camera: Camera | None, images: list[ImageRecord]) -> list[str]:
    """Why `camera` cannot be used for some of `images` (they will fail), in the words of the first
    one's CameraError. The camera is kept all the same: it may be meant for photos still to come."""
    if camera is None:
        return []
    failures: dict[tuple[int, int, int], str] = {}  # (width, height, EXIF orientation) -> why not
    for kind in {(r.width, r.height, r.exif.orientation) for r in images}:
        width, height, orientation = kind
        try:
            turned_camera(camera, orientation, width, height).for_image(width, height)
        except CameraError as exc:
            failures[kind] = str(exc)
    misfits = [failures[key] for r in images if (key := (r.width, r.height, r.exif.orientation)) in failures]
    if not misfits:
        return []
    which = "fits none" if len(misfits) == len(images) else f"does not fit {len(misfits)}"
    return [f"the camera {which} of the {len(images)} images held: {misfits[0]}"]


def camera_out(workspace: Workspace) -> CameraOut:
    snap = workspace.snapshot
    images = workspace.images()
    return CameraOut(camera=intrinsics(snap.camera), assumed_hfov_deg=snap.assumed_hfov_deg,
                     exif_images=sum(r.exif.camera is not None for r in images),
                     warnings=misfit_warnings(snap.camera, images))


def detail(workspace: Workspace, record: ImageRecord) -> ImageDetail:
    outcome = record.outcome  # once: summary, result and settings must come from the same run
    rec = outcome.recognition
    attempts = [] if rec is None else [
        AttemptOut(source=a.source, region=a.region, margin=a.margin,
                   winner=a.scores[a.winner].sign if a.winner is not None else None)
        for a in rec.attempts
    ]
    return ImageDetail(**summary(workspace, record, outcome).model_dump(),
                       result=rec.to_json(record.name) if rec else None, settings=rec.settings if rec else None,
                       camera=intrinsics(rec.camera) if rec else None, attempts=attempts)


def read_upload(file: FormFile, unnamed: str = "upload") -> tuple[str, bytes]:
    """(display name, bytes) of an uploaded file, named `unnamed` when the client sent no file name;
    the size is already bounded by UploadLimit."""
    return display_name(file.filename or unnamed), file.file.read()


def camera_from_upload(name: str, data: bytes) -> Camera:
    """Parse an uploaded camera file (any load_camera reads); CameraError names the upload, not a temp path."""
    suffix = Path(name).suffix.lower()
    with tempfile.TemporaryDirectory(prefix="signpose-camera-") as tmp:
        path = Path(tmp) / ("camera" + (suffix if suffix in CAMERA_SUFFIXES else ".yaml"))
        path.write_bytes(data)
        try:
            camera = load_camera(path)
        except CameraError as exc:
            raise CameraError(str(exc).replace(str(path), name)) from None
    return dataclasses.replace(camera, source=f"upload:{name}")


# ---------------------------------------------------------------- routes


def _error_handler(code: int):
    async def handler(request: Request, exc: Exception) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=code)
    return handler


def _problem(error: dict) -> str:
    """One pydantic validation error as `where: what`, without the input."""
    return f"{'.'.join(map(str, error['loc']))}: {error['msg']}"


async def _validation_error_handler(request: Request, exc: RequestValidationError) -> JSONResponse:
    """422 `{"detail": "<every problem, one line>"}` like every other error. FastAPI's default
    answers a list that echoes the input, and cannot encode it when it holds NaN or Infinity (a 500)."""
    return JSONResponse({"detail": "; ".join(map(_problem, exc.errors()))},
                        status_code=status.HTTP_422_UNPROCESSABLE_CONTENT)


class JsonBodyRequest(Request):
    """A request whose JSON body is read as signpose reads every JSON document (`parse_json`), with
    422 saying what is wrong: FastAPI read it with json.loads and answered what that cannot hold (nested
    some thousand levels deep, a whole number of thousands of digits) or bytes that are not UTF-8 with
    400 "There was an error parsing the body"."""

    async def json(self) -> Any:
        if not hasattr(self, "_json"):
            try:
                self._json = parse_json(await self.body())
            except JsonError as exc:  # FastAPI passes an HTTPException raised here on as it is
                raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"the body is {exc}") from None
        return self._json


class JsonBodyRoute(APIRoute):
    """An API route whose body FastAPI reads from a `JsonBodyRequest`."""

    def get_route_handler(self) -> Callable[[Request], Awaitable[Response]]:
        handler = super().get_route_handler()

        async def read_through(request: Request) -> Response:
            return await handler(JsonBodyRequest(request.scope, request.receive))
        return read_through


api = APIRouter(prefix="/api", route_class=JsonBodyRoute)
NUMERIC_SETTINGS = [f["name"] for f in settings_schema() if f["type"] in ("int", "float")]
INTEGER_SETTINGS = {f["name"] for f in settings_schema() if f["type"] == "int"}


@api.get("/health", response_model=Health, tags=["server"])
def health(workspace: WorkspaceDep) -> Health:
    return Health(version=package_version(), images=len(workspace.images()), busy=workspace.busy,
                  memory_held_bytes=workspace.memory_held(), memory_limit_bytes=workspace.config.max_memory_bytes)


@api.get("/events", response_class=EventSourceResponse, tags=["server"])
async def events(workspace: WorkspaceDep) -> AsyncIterable[ServerSentEvent]:
    """Server-sent events: `settings`, `results`, `library`, `camera`, `images`, `calibration` (payloads in
    the contract).

    Starts with the current `settings` and `results`. Events of one kind that arrive faster
    than they are sent collapse into the newest.
    """
    loop = asyncio.get_running_loop()
    latest: dict[str, dict] = {}
    wake = asyncio.Event()

    def store(event) -> None:
        latest[event.kind] = event.payload
        wake.set()

    unsubscribe = workspace.subscribe(lambda event: loop.call_soon_threadsafe(store, event))
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


# ---- settings

def settings_out(workspace: Workspace) -> SettingsOut:
    snap = workspace.snapshot
    return SettingsOut(version=snap.settings_version, settings=snap.settings)


@api.get("/settings", response_model=SettingsOut, tags=["settings"])
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


@api.put("/settings", response_model=SettingsOut, tags=["settings"], dependencies=[JSON_BODY])
def put_settings(changes: dict[str, Any], workspace: WorkspaceDep) -> SettingsOut:
    """Change some or all settings; every image is re-run (debounced). 422 names the bad value."""
    workspace.update_settings(changes)
    return settings_out(workspace)


@api.get("/settings/schema", response_model=list[SettingField], tags=["settings"])
def get_schema() -> list[dict]:
    return settings_schema()


@api.get("/presets", response_model=dict[str, Settings], tags=["settings"])
def get_presets() -> dict[str, Settings]:
    return PRESETS


@api.post("/settings/preset/{name}", response_model=SettingsOut, tags=["settings"])
def apply_preset(name: str, workspace: WorkspaceDep) -> SettingsOut:
    if name not in PRESETS:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no preset {name!r}; choose from {', '.join(PRESETS)}")
    workspace.replace_settings(PRESETS[name])
    return settings_out(workspace)


@api.get("/settings/export", tags=["settings"],
         responses={200: {"content": {"application/json": {}}, "description": "signpose-settings.json"}})
def export_settings(workspace: WorkspaceDep) -> Response:
    return Response(json.dumps(workspace.settings.to_dict(), indent=2) + "\n", media_type="application/json",
                    headers={"Content-Disposition": 'attachment; filename="signpose-settings.json"'})


@api.post("/settings/import", response_model=SettingsOut, tags=["settings"], dependencies=[MULTIPART, ONE_FILE])
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


# ---- library

@api.get("/library", response_model=list[SignOut], tags=["library"])
def get_library(workspace: WorkspaceDep) -> list[SignOut]:
    return [SignOut.of(s) for s in workspace.library.signs]


@api.get("/library/{sign_id}/image", response_class=FileResponse, tags=["library"])
def get_sign_image(sign_id: SignIdDep, workspace: WorkspaceDep) -> FileResponse:
    return FileResponse(workspace.sign_path(sign_id))


@api.post("/library", response_model=SignOut, status_code=status.HTTP_201_CREATED, tags=["library"],
          dependencies=[MULTIPART, ONE_FILE, single("id", "width_m", "name", "text", "height_m")])
def add_sign(file: Annotated[UploadFile, File(description="the sign, photographed flat or as artwork")],
             id: Annotated[str, Form(description="1-64 of a-z, 0-9, _ and -")],
             width_m: Annotated[float, Form(description="physical width, metres (0.02-10)")],
             workspace: WorkspaceDep,
             name: Annotated[str, Form()] = "", text: Annotated[str, Form()] = "",
             height_m: Annotated[float | None, Form(description="metres (0.02-10); default: from the image")] = None,
             ) -> SignOut:
    """Add a sign; 409 when its id is taken, or when its image cannot be told apart from a sign's already
    there (the message names it)."""
    _, data = read_upload(file)
    return SignOut.of(workspace.add_sign(id, data, name, text, width_m, height_m))


@api.delete("/library/{sign_id}", status_code=status.HTTP_204_NO_CONTENT, tags=["library"])
def delete_sign(sign_id: SignIdDep, workspace: WorkspaceDep) -> None:
    """Delete a sign; images whose result named it are re-run with the rest of the library."""
    workspace.remove_sign(sign_id)


# ---- images

@api.post("/images", response_model=UploadOut, status_code=status.HTTP_201_CREATED, tags=["images"],
          dependencies=[MULTIPART, FILES, IN_ORDER])
def add_images(files: Annotated[list[UploadFile], File(description="one or more images")],
               workspace: WorkspaceDep,
               expected: Annotated[list[str], Form(description='a sign id, "none" (no sign in the photo) or "" '
                                                               '(unlabelled): one for every file, or one per file '
                                                               'in their order')] = [],
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
    uploads = [(*read_upload(f), e) for f, e in zip(files, expected or [None] * len(files))]
    return UploadOut(images=[summary(workspace, r) for r in workspace.add_images(uploads, batch, position)])


@api.get("/images", response_model=ImagesOut, tags=["images"])
def list_images(workspace: WorkspaceDep) -> ImagesOut:
    progress = workspace.progress()
    return ImagesOut(version=progress["version"], running=progress["running"],
                     images=[summary(workspace, r) for r in workspace.images()])


@api.delete("/images", response_model=ImagesRemoved, tags=["images"])
def delete_images(workspace: WorkspaceDep) -> ImagesRemoved:
    """Remove every image at once (the page's "remove all"; a DELETE per image takes a request each)."""
    return ImagesRemoved(removed=workspace.remove_images())


@api.get("/images/{image_id}", response_model=ImageDetail, tags=["images"])
def get_image(record: RecordDep, workspace: WorkspaceDep) -> ImageDetail:
    return detail(workspace, record)


@api.patch("/images/{image_id}", response_model=ImageSummary, tags=["images"], dependencies=[JSON_BODY])
def set_expected(body: ExpectedIn, record: RecordDep, workspace: WorkspaceDep) -> ImageSummary:
    """Set or clear the label the image should get."""
    return summary(workspace, workspace.set_expected(record.id, body.expected))


@api.delete("/images/{image_id}", status_code=status.HTTP_204_NO_CONTENT, tags=["images"])
def delete_image(record: RecordDep, workspace: WorkspaceDep) -> None:
    try:
        workspace.remove_image(record.id)
    except KeyError:  # deleted by a concurrent request
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"image {record.id!r} was already deleted") from None


@api.get("/images/{image_id}/file", response_class=FileResponse, tags=["images"])
def get_image_file(record: RecordDep, workspace: WorkspaceDep) -> FileResponse:
    return FileResponse(workspace.image_path(record), media_type=record.media_type, filename=record.name,
                        content_disposition_type="inline")


@api.get("/images/{image_id}/stages/{stage}", tags=["images"],
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


@api.post("/recognize", response_model=RecognitionOut, tags=["images"], dependencies=[MULTIPART, ONE_FILE])
async def recognize_once(file: Annotated[UploadFile, File()], workspace: WorkspaceDep) -> dict:
    """Recognise one image with the current settings, library and camera without keeping it."""
    # The sync upload routes call read_upload directly; here, as in PUT /api/camera, the read goes
    # to a worker thread so that a large upload spooled to disk does not block the event loop.
    name, data = await run_in_threadpool(read_upload, file)
    rec = await within_time_limit(workspace, f"recognising {name}", lambda _: workspace.recognize_upload(data, name))
    return rec.to_json(name)


# ---- tuning

@api.post("/calibrate/threshold", response_model=CalibrateOut, tags=["tuning"], dependencies=[JSON_BODY])
def calibrate_threshold(body: CalibrateIn, workspace: WorkspaceDep) -> tuning.ThresholdSuggestion:
    """Measure the sign's white and suggest a threshold just below it (the paper: 0.8 measured, 0.75 set)."""
    record = find_record(workspace, body.image_id)
    w, h = record.width, record.height
    if body.rect is not None:
        x0, y0, x1, y1 = body.rect
        x0, y0, x1, y1 = max(0, x0), max(0, y0), min(w, x1), min(h, y1)
        if x1 - x0 < 2 or y1 - y0 < 2:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"rect {list(body.rect)} does not cover at least 2x2 px of the {w}x{h} image; "
                                "give [x0, y0, x1, y1] in image pixels with x0 < x1 and y0 < y1")
        inside, source = tuning.rect_mask((x0, y0, x1, y1), w, h), "rectangle"
    else:
        region = tuning.sign_region(result_of(record).recognition, w, h)
        if region is None:
            # The page words this for its own users (static/detail.js): they drag a box.
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"no sign or white blob was found in {record.name}; send rect [x0, y0, x1, y1] "
                                "in image pixels around the sign, with some wall in it")
        inside, source = region
    return tuning.suggest_threshold(record.gray, workspace.settings.normalization, inside, source)


def taken_sweep_values(settings: Settings, param: str, lo: float, hi: float, values: list[float]) -> list[float]:
    """The `values` of a sweep of `param` from `lo` to `hi` that `param` can take beside `settings`.

    An end out of the setting's own range is a 422 naming it as given: the error was the first value refused,
    often one between them that nobody typed. Values that contradict another setting are left out (a
    max_crop_size swept up from 0, never downscale, passes sizes below min_crop_size); a 422 when that is all."""
    for end, given, value in (("lo", lo, values[0]), ("hi", hi, values[-1])):
        try:
            check_setting(param, value)
        except SettingsError as exc:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"{end} ({given:g}): {exc}") from None
    taken = [value for value in values if refusal(settings, param, value) is None]
    if not taken:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"no value of {param} from lo ({lo:g}) to hi "
                            f"({hi:g}) goes with the other settings: {refusal(settings, param, values[0])}")
    return taken


def refusal(settings: Settings, param: str, value: float) -> SettingsError | None:
    """Why `settings` with `param` set to `value` are invalid; None when they are not."""
    try:
        settings.replace(**{param: value})
    except SettingsError as exc:
        return exc
    return None


@api.get("/sweep", response_model=SweepOut, tags=["tuning"])
async def sweep(workspace: WorkspaceDep,
          param: Annotated[str, Query(description=f"a numeric setting: {', '.join(NUMERIC_SETTINGS)}")] = "threshold",
          lo: float = 0.3, hi: float = 0.9,
          steps: Annotated[int, Query(ge=2, le=MAX_SWEEP_STEPS)] = 13) -> SweepOut:
    """Re-run every labelled image for each of `steps` values of `param` from `lo` to `hi`."""
    if param not in NUMERIC_SETTINGS:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"cannot sweep {param!r}; choose a numeric setting: {', '.join(NUMERIC_SETTINGS)}")
    if not lo < hi:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"lo ({lo}) must be below hi ({hi})")
    values = taken_sweep_values(workspace.settings, param, lo, hi, tuning.sweep_values(lo, hi, steps,
                                                                                      param in INTEGER_SETTINGS))
    labelled = [r for r in workspace.images() if r.expected is not None]
    if not labelled:
        raise HTTPException(status.HTTP_409_CONFLICT,
                            "no labelled images to sweep over: give images an expected label "
                            "(when uploading, or PATCH /api/images/{id})")
    runs = await within_time_limit(workspace, f"the sweep of {param} over {len(labelled)} images",
                                   lambda stop: workspace.sweep(param, values, labelled, stop))
    correct, min_margin, by_plaque, failed = [], [], [], []
    for recs in runs:
        good = [rec for record, rec in zip(labelled, recs) if rec is not None and is_correct(record.expected, rec)]
        correct.append(len(good))
        failed.append(sum(rec is None for rec in recs))
        # The plaque fallback matches no features: its margin is no inlier margin.
        min_margin.append(min((rec.margin for rec in good if rec.recognized and not rec.by_plaque), default=None))
        by_plaque.append(sum(rec.by_plaque for rec in good))
    band = tuning.working_band(values, [c == len(labelled) for c in correct])
    return SweepOut(param=param, values=values, correct=correct, min_margin=min_margin, by_plaque=by_plaque,
                    failed=failed, band=band, centre=tuning.band_centre(values, band, param in INTEGER_SETTINGS),
                    labelled=len(labelled))


# ---- camera

@api.get("/camera", response_model=CameraOut, tags=["camera"])
def get_camera(workspace: WorkspaceDep) -> CameraOut:
    return camera_out(workspace)


@api.put("/camera", response_model=CameraOut, tags=["camera"], openapi_extra={"requestBody": {
    "required": True,
    "description": "JSON intrinsics {fx, fy, cx, cy, ...}, or the keys of a JSON camera file (K or camera_matrix, "
                   "D or distortion_coefficients, ...), read as a camera file of the same content is (a key it "
                   "refuses, such as k1, is 422); or a camera file uploaded",
    "content": {
        "application/json": {"schema": CameraModel.model_json_schema()},
        "multipart/form-data": {"schema": {
            "type": "object", "required": ["file"],
            "properties": {"file": {"type": "string", "format": "binary",
                                    "description": "ROS camera_info YAML (file, or message as ros2 topic echo "
                                                   "prints it), OpenCV FileStorage YAML/XML/JSON, a Kalibr "
                                                   "camchain of one camera, or {fx, fy, cx, cy}"}},
        }},
    },
}})
async def put_camera(request: Request, workspace: WorkspaceDep) -> CameraOut:
    """Set the camera from JSON intrinsics or an uploaded camera file; every image is re-run."""
    content_type = request.headers.get("content-type", "")
    if content_type.startswith("multipart/form-data"):
        async with request.form() as form:
            name, data = await run_in_threadpool(read_upload, the_file(form), "camera")
        camera = await run_in_threadpool(camera_from_upload, name, data)
    elif content_type.startswith("application/json"):
        # Read as every route reads its body (JsonBodyRequest), not by pydantic's parser, which takes the
        # last of a key given twice without a word; then as a camera file of the same content is, not by
        # CameraModel (the body's schema for /docs), which dropped the keys it has not (D beside fx: no
        # distortion; k1, a fisheye model) without a word.
        camera = camera_from_json(await request.json(), source="json")
    else:
        raise HTTPException(status.HTTP_415_UNSUPPORTED_MEDIA_TYPE,
                            "send JSON intrinsics {fx, fy, cx, cy, dist, width, height} "
                            "or a multipart camera file in the field 'file'")
    await run_in_threadpool(workspace.set_camera, camera)
    return await run_in_threadpool(camera_out, workspace)


@api.get("/camera/file", tags=["camera"], responses={404: {"description": "no camera is set"}})
def get_camera_file(workspace: WorkspaceDep) -> dict[str, Any]:
    """The camera in use as a JSON camera file gives it, which PUT /api/camera takes back as it is:
    a camera of part of its sensor as the whole sensor's intrinsics and size with its `roi` and
    `binning_x`, `binning_y`, where GET /api/camera gives those of the images."""
    camera = workspace.snapshot.camera
    if camera is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            "no camera is set: each image uses its EXIF focal length, else the assumed field of view")
    return camera.file_json()


@api.delete("/camera", response_model=CameraOut, tags=["camera"])
def delete_camera(workspace: WorkspaceDep) -> CameraOut:
    """Forget the camera: per image, its EXIF focal length if it has one, else the assumed field of view."""
    workspace.set_camera(None)
    return camera_out(workspace)


@api.put("/camera/assumed", response_model=CameraOut, tags=["camera"], dependencies=[JSON_BODY])
def put_assumed_fov(body: AssumedFovIn, workspace: WorkspaceDep) -> CameraOut:
    """The horizontal field of view to assume for images without camera or EXIF; they are re-run."""
    workspace.set_assumed_hfov(body.hfov_deg)
    return camera_out(workspace)


# ---- camera calibration from chessboard photos (app/calibration.py)

def calibration_out(calibration: CalibrationSession, state: CalibrationState) -> CalibrationOut:
    """The response for `state`, a state of `calibration` (read once by the caller: photos, board
    and result must agree)."""
    summary = state.result.to_json() if state.result is not None else None
    # Without a result, the photos the last run dropped as outliers are still out (`unfitted` counts without them).
    left_out = state.recipe.left_out if state.recipe else frozenset()
    other_sizes = state.other_sizes
    views = [CalibrationView(**(summary["views"][i] if summary else
                                {"name": p.name, "found": p.view.found, "excluded": p.id in left_out}),
                             id=p.id, width=p.view.image_size[0], height=p.view.image_size[1],
                             other_size=other_sizes.get(p.id))
             for i, p in enumerate(state.photos)]
    result = None if summary is None else CalibrationResult.model_validate(
        {**summary, "camera": intrinsics(calibrated_camera(state.result)),
         "outlier_advice": page_outlier_advice(state.result)})
    search = calibration.search
    return CalibrationOut(revision=state.revision, min_views=MIN_VIEWS, max_views=calibration.max_photos,
                          max_square_m=MAX_SQUARE_M, views=views,
                          hint=state.few_boards_advice,
                          board=BoardSpec(cols=state.board[0], rows=state.board[1], square_m=state.square_m),
                          search=None if search is None else BoardSearchOut(**search.to_json()),
                          result=result, unfitted=state.unfitted, size_mismatch=state.size_mismatch)


def no_such_photo(view_id: str) -> HTTPException:
    return HTTPException(status.HTTP_404_NOT_FOUND,
                         f"no calibration photo with id {view_id!r}; GET /api/calibration lists them")


def fitted(state: CalibrationState) -> Calibration:
    """The state's calibration; 409 saying why there is none."""
    if state.result is None:
        raise Conflict(state.why_no_result)
    return state.result


@api.get("/calibration", response_model=CalibrationOut, tags=["calibration"])
def get_calibration_state(calibration: CalibrationDep) -> CalibrationOut:
    """The board, every photo (board found or not, its error), and the result of the last run, if current."""
    return calibration_out(calibration, calibration.state)


@api.post("/calibration/images", response_model=CalibrationAdded, status_code=status.HTTP_201_CREATED,
          tags=["calibration"], dependencies=[MULTIPART, FILES, IN_ORDER])
def add_calibration_photos(files: Annotated[list[UploadFile], File(description="photos of the chessboard")],
                           calibration: CalibrationDep, batch: Batch = "", position: Position = 0) -> CalibrationAdded:
    """Add photos and search each for the board (all or nothing). The last result is dropped.
    Listed after those held, or with `batch`, by `position` among its files; `added` names them."""
    state, added = calibration.add([read_upload(f) for f in files], batch, position)
    return CalibrationAdded(**calibration_out(calibration, state).model_dump(), added=added)


@api.delete("/calibration", response_model=CalibrationOut, tags=["calibration"])
def clear_calibration(calibration: CalibrationDep) -> CalibrationOut:
    """Forget every calibration photo (the board size stays; the workspace camera is not touched)."""
    return calibration_out(calibration, calibration.clear())


@api.put("/calibration/board", response_model=CalibrationOut, tags=["calibration"], dependencies=[JSON_BODY])
def set_calibration_board(body: BoardSpec, calibration: CalibrationDep) -> CalibrationOut:
    """Set the board; every photo is searched again when the corner counts change. 422 names a bad value."""
    return calibration_out(calibration, calibration.set_board((body.cols, body.rows), body.square_m))


@api.post("/calibration/run", response_model=CalibrationOut, tags=["calibration"], dependencies=[OPTIONAL_JSON_BODY])
def run_calibration(calibration: CalibrationDep, body: CalibrationRunIn | None = None) -> CalibrationOut:
    """Fit the intrinsics to the photos where the board was found, on the board set (422 says why it
    cannot). The body is optional: without one, `drop_outliers` is false."""
    return calibration_out(calibration, calibration.run((body or CalibrationRunIn()).drop_outliers))


@api.get("/calibration/views/{view_id}/image", tags=["calibration"],
         responses={200: {"content": {"image/jpeg": {}}, "description": "JPEG figure"}})
def get_calibration_view(view_id: str, calibration: CalibrationDep,
                         overlay: Annotated[Literal["corners", "undistorted"], Query(
                             description="corners: the corners found; undistorted: undistorted by the result")]
                         = "corners",
                         max_side: Annotated[int, Query(ge=32, le=PREVIEW_MAX_SIDE)] = PREVIEW_MAX_SIDE) -> Response:
    """One calibration photo with the board's corners drawn (header X-Calibration-Revision)."""
    state = calibration.state  # once: photo, board and result must agree
    try:
        photo = state.photo(view_id)
    except KeyError:
        raise no_such_photo(view_id) from None
    camera = fitted(state).camera if overlay == "undistorted" else None
    img = figures.draw_board(photo.preview, photo.view, state.board, camera, max_side)
    return Response(figures.jpeg(img), media_type="image/jpeg",
                    headers={"X-Calibration-Revision": str(state.revision)})


@api.delete("/calibration/views/{view_id}", status_code=status.HTTP_204_NO_CONTENT, tags=["calibration"])
def delete_calibration_view(view_id: str, calibration: CalibrationDep) -> None:
    """Forget one photo; after a run, the photos left are fitted again as it fitted them (those it left
    out stay out), after every removal; when they give no result, `unfitted` and the 409 of GET
    /api/calibration/camera.yaml say why."""
    try:
        calibration.remove(view_id)
    except KeyError:
        raise no_such_photo(view_id) from None


@api.post("/calibration/apply", response_model=CameraOut, tags=["calibration"])
def apply_calibration(calibration: CalibrationDep, workspace: WorkspaceDep) -> CameraOut:
    """Use the calibrated camera for every image (as PUT /api/camera does); they are re-run."""
    workspace.set_camera(calibrated_camera(fitted(calibration.state)))
    return camera_out(workspace)


@api.get("/calibration/camera.yaml", tags=["calibration"],
         responses={200: {"content": {"application/x-yaml": {}}, "description": "ROS camera_info YAML"}})
def get_calibration_yaml(calibration: CalibrationDep) -> Response:
    """The calibrated camera as a ROS camera_info file (signpose recognize --camera reads it)."""
    return Response(ros_camera_yaml(calibrated_camera(fitted(calibration.state))), media_type="application/x-yaml",
                    headers={"Content-Disposition": 'attachment; filename="camera.yaml"'})


@api.put("/scene/canvas", status_code=status.HTTP_204_NO_CONTENT, tags=["scene"], dependencies=[JSON_BODY])
def put_scene_canvas(canvas: CanvasScaleIn, request: Request, viewer: Annotated[int, Query(
        ge=0, description="the viser client whose canvas this is: viser's page is told its id")]) -> None:
    """How many device px a 3D viewer's canvas (of this size as viser reports it) has to the CSS px:
    viser's client reports its canvas in device px but draws the camera labels at a size in CSS px,
    and the scene lays them out in CSS px. viser's page sends this (static/viser-canvas.js)."""
    scene = request.app.state.scene
    if scene is not None:
        scene.set_canvas_width(viewer, canvas.width / canvas.px_per_css_px)


def _attach_scene(server: viser.ViserServer, workspace: Workspace):
    """The colleague-owned viser scene, when app/scene.py exists; its handle (with close()) or None."""
    try:
        from signpose.app import scene
    except ModuleNotFoundError as exc:
        if exc.name != "signpose.app.scene":
            raise
        return None
    return scene.attach(server, workspace)


def create_app(source: Workspace | WorkspaceConfig, token: str | None = None) -> FastAPI:
    """The signpose app around `source`: a Workspace the caller owns and closes, or a config to
    build one from (then the app closes it at shutdown). The viser server starts with the app.

    With `token`, every request and websocket must carry it (app/security.py); without, only
    requests addressed to a loopback host are answered.
    """
    owned = not isinstance(source, Workspace)
    workspace = Workspace(source) if owned else source

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        # viser prints its private address unconditionally; people should only see ours.
        with contextlib.redirect_stdout(io.StringIO()):
            private = PrivateViser.start()
        app.state.viser_socket = private.socket_path
        scene = app.state.scene = _attach_scene(private.server, workspace)
        try:
            yield
        finally:
            if scene is not None:
                scene.close()
            private.stop()
            if owned:
                await run_in_threadpool(workspace.close)

    # Swagger UI and ReDoc from files installed with the package: a competition venue may have no internet.
    app = FastAPIOffline(title="signpose", version=package_version(), lifespan=lifespan, static_url=DOCS_ASSETS,
                         summary="Recognise known planar signs and recover the camera pose; tune every step.")
    app.state.workspace = workspace
    app.state.scene = None   # until the lifespan attaches it
    app.state.calibration = CalibrationSession(workspace.config.max_pixels,
                                               publish=lambda payload: workspace.publish("calibration", payload))
    # The last added runs first: headers on every answer, then access, then the body limit.
    app.add_middleware(UploadLimit, max_bytes=workspace.config.max_upload_bytes)
    app.add_middleware(AccessGuard, token=token)
    app.add_middleware(SecurityHeaders)
    for error, code in ((SettingsError, 422), (CameraError, 422), (LibraryError, 422), (ImageError, 422),
                        (PipelineError, 422), (CalibrationError, 422), (ImageTooLarge, 413), (Conflict, 409)):
        app.add_exception_handler(error, _error_handler(code))
    app.add_exception_handler(RequestValidationError, _validation_error_handler)
    app.include_router(api)
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
