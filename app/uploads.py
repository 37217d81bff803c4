"""What `signpose serve` accepts as uploads: the size of a request body (`UploadLimit`, the
middleware), the multipart fields a route reads (files that are files, one value where one is
meant), and an upload's display name and bytes (`read_upload`).

The checks raise HTTPException with what to send instead; app/api/deps.py runs them as
dependencies of the multipart routes, before FastAPI reads the fields its own way.
"""

from __future__ import annotations

import math

from fastapi import HTTPException, status
from fastapi.responses import JSONResponse
from starlette.datastructures import FormData, Headers, UploadFile
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from .image_store import display_name


class UploadLimit:
    """Refuse request bodies over `max_bytes` with 413: at once when Content-Length says so,
    else as soon as the bytes received pass the limit, so nothing larger is ever buffered.
    `routes`: paths whose bodies have a limit of their own, path -> (bytes, the serve option that sets
    it): a flight's video is one request far larger than a photo."""

    def __init__(self, app: ASGIApp, max_bytes: int, routes: dict[str, tuple[int, str]] | None = None) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.routes = routes or {}

    def limit(self, path: str) -> tuple[int, str]:
        """(the largest body in bytes, the option that sets it) for a request to `path`."""
        return self.routes.get(path.rstrip("/"), (self.max_bytes, "--max-upload-mb"))

    def message(self, size: int | None, path: str = "") -> str:
        """Why a body of `size` bytes (None: not declared) is refused, and what to do: the page sends one
        file per request, so a single large photo can only pass with the limit raised where it is set."""
        max_bytes, option = self.limit(path)
        size_text = f"{size / 1e6:.1f} MB, " if size is not None else ""
        enough = f" {math.ceil(size / 1e6)}" if size is not None else ""
        return (f"the upload is {size_text}more than this server's limit of {max_bytes / 1e6:.1f} MB per request: "
                f"send fewer or smaller files per request, or start the server with a higher limit "
                f"(signpose serve {option}{enough})")

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        path = scope.get("path", "")
        max_bytes = self.limit(path)[0]
        declared = Headers(scope=scope).get("content-length", "")
        if declared.isdigit() and int(declared) > max_bytes:
            await JSONResponse({"detail": self.message(int(declared), path)}, status.HTTP_413_CONTENT_TOO_LARGE)(
                scope, receive, send)
            return
        received = 0

        async def counting_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > max_bytes:
                    # Raised inside the app's body parsing; FastAPI turns it into the response.
                    raise HTTPException(status.HTTP_413_CONTENT_TOO_LARGE, self.message(None, path))
            return message

        await self.app(scope, counting_receive, send)


def uploads(form: FormData, field: str) -> list[UploadFile]:
    """The files in the multipart `field`; 422 naming the part that is not a file. A part sent
    without a file name (a text field, or a file whose name was left empty) is text to multipart,
    and FastAPI would refuse it as "Expected UploadFile, received: <class 'str'>"."""
    values = form.getlist(field)
    files: list[UploadFile] = []
    for i, value in enumerate(values, 1):
        if not isinstance(value, UploadFile):
            which = f"part {i} of {len(values)} in" if len(values) > 1 else "the part in"
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"{which} the multipart field {field!r} is not a file: it has no file name, so it "
                                f"arrived as text; send each file with its name, as a browser form or "
                                f"curl -F '{field}=@<path>' does")
        files.append(value)
    return files


def the_file(form: FormData) -> UploadFile:
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


def single_values(form: FormData, fields: tuple[str, ...]) -> None:
    """422 when one of the text `fields` is sent several times, as `the_file` refuses several files:
    a route reading it as one value would take the last silently."""
    for field in fields:
        if (count := len(form.getlist(field))) > 1:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"got {count} values in the multipart field {field!r}; it takes one, so send it once")


def in_order(form: FormData) -> None:
    """422 unless `batch` and `position` are sent once each (`single_values`) and `position` with a `batch`:
    alone it would be ignored, and the files listed in the order they land rather than the one meant."""
    single_values(form, ("batch", "position"))
    if "position" in form and not form.get("batch"):
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            "'position' is the place of this request's files within a 'batch' and needs one: send "
                            "'batch' too, the same name in every request of the batch, or leave 'position' out")


def read_upload(file: UploadFile, unnamed: str = "upload") -> tuple[str, bytes]:
    """(display name, bytes) of an uploaded file, named `unnamed` when the client sent no file name;
    the size is already bounded by UploadLimit."""
    return display_name(file.filename or unnamed), file.file.read()
