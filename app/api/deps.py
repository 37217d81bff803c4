"""What the API's routes share: the objects they work on (the workspace, an image, a sign, the
calibration session, the flights, the sign map, the 3D scene, the queue heavy work waits in) as
FastAPI dependencies, the checks of a request's body (its media type, its multipart fields), and the route class that reads
bodies.

The objects live on `app.state` (app/server.py's `create_app` puts them there); a route asks for
one by its parameter type (`WorkspaceDep`, ...), never through a module global, so that every app
built in one process (the tests build many) has its own.
"""

from __future__ import annotations

from collections.abc import Callable, Coroutine, Iterable
from typing import Annotated, Any

from fastapi import Depends, Form, HTTPException, Request, Response, status
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute
from python_multipart.exceptions import MultipartParseError
from python_multipart.multipart import DEFAULT_MAX_HEADER_SIZE
from starlette.datastructures import FormData
from starlette.exceptions import HTTPException as StarletteHTTPException

from signpose.pipeline.jsonfile import JsonError, parse_json
from signpose.pipeline.library import ID_PATTERN

from ..calibration import CalibrationSession
from ..flights import Flights
from ..heavy import WorkQueue
from ..scene import SceneHandle
from ..security import TOKEN_QUERY, cross_site_refusal
from ..sign_maps import SignMaps
from ..uploads import in_order, single_values, the_file, uploads
from ..image_store import IMAGE_ID, ImageRecord
from ..workspace import Workspace

# ---------------------------------------------------------------- what routes work on


# The getters are `async`: FastAPI runs a plain `def` dependency in the thread pool, a wait for
# a thread to read an attribute.


async def get_workspace(request: Request) -> Workspace:
    return request.app.state.workspace


WorkspaceDep = Annotated[Workspace, Depends(get_workspace)]


def find_record(workspace: Workspace, image_id: str) -> ImageRecord:
    """The image `image_id` of `workspace`; 404 saying where the ids are listed."""
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


async def get_calibration(request: Request) -> CalibrationSession:
    return request.app.state.calibration


CalibrationDep = Annotated[CalibrationSession, Depends(get_calibration)]


async def get_scene(request: Request) -> SceneHandle | None:
    """The viser scene, None until the app's lifespan has attached it."""
    return request.app.state.scene


SceneDep = Annotated[SceneHandle | None, Depends(get_scene)]


async def get_flights(request: Request) -> Flights:
    return request.app.state.flights


FlightsDep = Annotated[Flights, Depends(get_flights)]


async def get_sign_maps(request: Request) -> SignMaps:
    return request.app.state.sign_maps


SignMapsDep = Annotated[SignMaps, Depends(get_sign_maps)]


async def get_work_queue(request: Request) -> WorkQueue:
    """The queue heavy work waits in (app/heavy.py); 403 when a browser sent the request from another
    site's page: a GET is not Origin-checked as writes are, and an `<img>` tag could start a sweep."""
    refusal = cross_site_refusal(request.headers)
    if refusal is not None:
        raise HTTPException(status.HTTP_403_FORBIDDEN, refusal)
    return request.app.state.work_queue


# A route taking this is heavy: it runs its work through the queue, and only for its own page or a script.
WorkQueueDep = Annotated[WorkQueue, Depends(get_work_queue)]


# ---------------------------------------------------------------- request bodies


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


def form_check(check: Callable[[FormData], object]) -> Any:
    """A dependency of multipart routes that runs `check` (raising HTTPException) on the form FastAPI
    has already parsed (and will close), before FastAPI reads its fields its own way."""
    async def dependency(request: Request) -> None:
        check(await request.form())
    return Depends(dependency)


ONE_FILE = form_check(the_file)  # routes whose `file` parameter takes one upload
FILES = form_check(lambda form: uploads(form, "files"))  # routes whose `files` parameter takes uploads
IN_ORDER = form_check(in_order)  # routes that take `batch` and `position`


def single(*fields: str) -> Any:
    """A dependency of the multipart routes that read each of the text `fields` as one value (`single_values`)."""
    return form_check(lambda form: single_values(form, fields))


# The longest file name a browser's part header leaves room for, in hundreds of characters.
FILE_NAME_CHARS = (DEFAULT_MAX_HEADER_SIZE - len('Content-Disposition: form-data; name="files"; filename=""')) // 100 * 100
LONG_PART_HEADER = (f"a part of the multipart body has a header line longer than {DEFAULT_MAX_HEADER_SIZE} bytes, "
                    f"the parser's limit: a file name longer than about {FILE_NAME_CHARS:,} characters (fewer "
                    "outside ASCII); send the file under a shorter name")

# The multipart fields of the routes that take a batch of uploads a request each (workspace.Slot).
Batch = Annotated[str, Form(max_length=64, description="a name the client gives a batch of files it sends a "
                                                       "request each, several at once: they are listed by "
                                                       "`position`, whatever order they land in")]
Position = Annotated[int, Form(ge=0, description="the place in `batch` of this request's first file; "
                                                "only with `batch`")]


class JsonBodyRequest(Request):
    """A request whose JSON body is read as signpose reads every JSON document (`parse_json`), with
    422 saying what is wrong: FastAPI read it with json.loads and answered what that cannot hold (nested
    some thousand levels deep, a whole number of thousands of digits) or bytes that are not UTF-8 with
    400 "There was an error parsing the body". A multipart body whose part header is too long (a file
    name of over about 4,100 characters) is refused with 422 saying so, not Starlette's bare 400
    "Invalid multipart data."."""

    async def _get_form(self, *, max_files: int | float = 1000, max_fields: int | float = 1000,
                        max_part_size: int = 1024 * 1024) -> FormData:
        try:
            return await super()._get_form(max_files=max_files, max_fields=max_fields, max_part_size=max_part_size)
        except StarletteHTTPException as exc:
            # Starlette raises it (its own, which FastAPI's subclasses) while handling its
            # MultiPartException, itself raised from the parser's error.
            cause = exc.__context__.__cause__ if exc.__context__ is not None else None
            if isinstance(cause, MultipartParseError) and "header size" in str(cause):
                raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, LONG_PART_HEADER) from None
            raise

    async def json(self) -> Any:
        if not hasattr(self, "_json"):
            try:
                self._json = parse_json(await self.body())
            except JsonError as exc:  # FastAPI passes an HTTPException raised here on as it is
                raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"the body is {exc}") from None
        return self._json


class JsonBodyRoute(APIRoute):
    """An API route whose body FastAPI reads from a `JsonBodyRequest`; every router of the API uses it.

    A form field or query parameter the route does not take is refused (422 naming it and those it takes)
    rather than dropped: `POST /api/recognize?min_inliers=1000` answered as if it had been applied. Query
    parameters are checked on routes that change something: a GET may carry a page's cache-busting `v`."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()
        query = names(self.dependant, "query_params")
        form = names(self.dependant, "body_params")  # empty for a route that reads its form itself

        async def read_through(request: Request) -> Response:
            request = JsonBodyRequest(request.scope, request.receive)
            if request.method != "GET":  # the access token may come in the query of any request
                refuse_unknown("query parameter", request.query_params.keys() - {TOKEN_QUERY}, query)
            if form and request.headers.get("content-type", "").startswith("multipart/form-data"):
                refuse_unknown("form field", (await request.form()).keys(), form)
            return await handler(request)
        return read_through


def names(dependant: Dependant, kind: str) -> set[str]:
    """The names of the `kind` parameters ("query_params", "body_params") of `dependant` and its dependencies."""
    return {param.alias for param in getattr(dependant, kind)}.union(
        *(names(sub, kind) for sub in dependant.dependencies))


def refuse_unknown(what: str, given: Iterable[str], known: set[str]) -> None:
    """422 naming the `given` names (of a `what`) not `known`, and those that are."""
    unknown = sorted(set(given) - known)
    if unknown:
        takes = f"this request takes {', '.join(map(repr, sorted(known)))}" if known else "this request takes none"
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"unknown {what}{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))}: {takes}")

