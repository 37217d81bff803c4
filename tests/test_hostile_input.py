"""Hostile and odd input against a real server: a clear 4xx for what cannot be used, a result for
every image that can, nothing written where a client names a path, and the server goes on serving.

Complements test_api.py (empty, text-as-JPEG, truncated and bomb uploads, oversized bodies, the
common bad settings and camera values) with the rest: odd image formats, hostile names and ids, state
changed under a running request.
"""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest
from PIL import Image

import signpose.app.image_store as image_store
from signpose.app.api.deps import FILE_NAME_CHARS
from signpose.app.figures import DIM, MIN_SIDE_PX, RED, STAGES
from signpose.app.server import create_app
from signpose.app.workspace import WorkspaceConfig
from signpose.pipeline.library import SAMPLE_LIBRARY, load_library
from tests.support.scene_images import has, png_bomb, sign_photo
from tests.support.serving import TIMEOUT_S, assert_error, http_exchange, running, upload, wait_idle

# Hostile requests to a real uvicorn server.
pytestmark = pytest.mark.server

LIBRARY = load_library(SAMPLE_LIBRARY)
STORED_NAME = re.compile(r"^[0-9a-f]{12}\.\w+$")


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    """A folder holding the state directory and nothing else: what may be written outside it shows here."""
    return tmp_path_factory.mktemp("hostile")


@pytest.fixture(scope="module")
def base_url(root):
    config = WorkspaceConfig(state_dir=root / "state", load_samples=False, workers=2, max_upload_bytes=2_000_000)
    with running(create_app(config)) as url:
        yield url


@pytest.fixture
def client(base_url):
    with httpx.Client(base_url=base_url, timeout=TIMEOUT_S) as c:
        yield c
        assert c.get("/api/health").json()["status"] == "ok"  # still serving, whatever the test sent


def image_count(client) -> int:
    return len(client.get("/api/images").json()["images"])


def processed(client, image_id: str) -> dict:
    """The image's detail once it has a result for the current settings: these tests upload one image
    at a time and make no change that re-runs them, so it is the one the server is busy with."""
    wait_idle(client)
    return client.get(f"/api/images/{image_id}").json()


def encode(image: Image.Image, fmt: str, **options) -> bytes:
    out = io.BytesIO()
    image.save(out, fmt, **options)
    return out.getvalue()


def outside_state(root: Path) -> set[str]:
    """Every path under `root` except inside its state directory."""
    return {str(p.relative_to(root)) for p in root.rglob("*") if "state" not in p.relative_to(root).parts}


def multipart(filename: bytes, data: bytes, field: bytes = b"files") -> tuple[bytes, bytes]:
    """(content type, body) of a one-file multipart form, the file name as raw bytes (any encoding)."""
    body = (b"--b\r\nContent-Disposition: form-data; name=\"" + field + b"\"; filename=\"" + filename + b"\"\r\n"
            b"Content-Type: image/jpeg\r\n\r\n" + data + b"\r\n--b--\r\n")
    return b"multipart/form-data; boundary=b", body


def raw_post(base_url: str, path: str, content_type: bytes, body: bytes) -> tuple[int, dict]:
    head = (b"POST " + path.encode() + b" HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: " + content_type +
            b"\r\nContent-Length: " + str(len(body)).encode() + b"\r\nConnection: close\r\n\r\n")
    return http_exchange(base_url, head, [body])


# ---------------------------------------------------------------- unusable files

def test_a_header_claiming_50000x50000_px_is_refused_before_decoding(client, monkeypatch):
    decoded = []
    monkeypatch.setattr(image_store, "decode_with_exif", lambda *a: decoded.append(a) or pytest.fail("decoded"))
    bomb = png_bomb(50_000, 50_000)
    assert len(bomb) < 200
    assert_error(upload(client, ("bomb.png", bomb, None)), 413, "bomb.png", "megapixels", "downscale")
    assert_error(client.post("/api/recognize", files={"file": ("bomb.png", bomb, "image/png")}), 413, "megapixels")
    assert decoded == [] and image_count(client) == 0


@pytest.mark.parametrize("name, data, words", [
    ("report.jpg", b"%PDF-1.7\n1 0 obj << /Type /Catalog >> endobj\ntrailer << >>\n%%EOF\n", ("report.jpg", "not an image")),
    ("page.jpg", b"<html><script>alert(1)</script></html>", ("not an image",)),
    ("header_only.jpg", b"\xff\xd8\xff\xe0\x00\x10JFIF\x00", ("header_only.jpg",)),
    ("zeros.png", b"\x00" * 4096, ("not an image",)),
])
def test_files_that_are_not_images_are_refused(client, name, data, words):
    assert_error(upload(client, (name, data, None)), 422, *words)
    assert_error(client.post("/api/recognize", files={"file": (name, data, "image/jpeg")}), 422, *words)
    assert image_count(client) == 0


def test_every_unusable_file_of_an_upload_is_named_and_none_is_added(client):
    """All or nothing, as the API says, but only the first unusable file was named: a script sending a folder
    learnt of the next one on its next try. One too large is named with the others, found from its header; when
    each is, the answer is 413."""
    photo = sign_photo(LIBRARY, "chief_of_security")
    r = upload(client, ("good.jpg", photo, None), ("notes.jpg", b"meeting at 10", None),
               ("bomb.png", png_bomb(50_000, 50_000), None), ("cut.jpg", photo[:len(photo) // 2], None))
    assert_error(r, 422, "3 of the 4 files cannot be used, so none was added: (1) notes.jpg: not an image file",
                 "; (2) bomb.png: 50000x50000 px is 2500.0 megapixels, more than the 179",
                 "; (3) cut.jpg: damaged or truncated JPEG file")
    assert image_count(client) == 0
    bombs = upload(client, ("a.png", png_bomb(50_000, 50_000), None), ("b.png", png_bomb(60_000, 60_000), None))
    assert_error(bombs, 413, "2 of the 2 files cannot be used", "(1) a.png: 50000x50000 px", "(2) b.png: 60000x60000")
    assert image_count(client) == 0


def test_wrong_content_types_are_415(client):
    photo = sign_photo(LIBRARY, "security_compound")
    for path in ("/api/images", "/api/recognize", "/api/settings/import", "/api/library"):
        assert_error(client.post(path, content=photo, headers={"content-type": "image/jpeg"}), 415, "multipart")
    assert_error(client.put("/api/settings", content=b"threshold=0.7"), 415, "application/json")
    assert_error(client.put("/api/settings", content=b'{"ratio": 0.7}', headers={"content-type": "text/plain"}),
                 415, "application/json")
    assert_error(client.post("/api/calibrate/threshold", content=b"{}", headers={"content-type": "text/plain"}), 415)
    # A file part's declared type is not trusted either way: the bytes decide.
    r = client.post("/api/images", files={"files": ("fine.jpg", photo, "text/plain")})
    assert r.status_code == 201
    image_id = r.json()["images"][0]["id"]
    assert client.get(f"/api/images/{image_id}/file").headers["content-type"] == "image/jpeg"
    assert client.delete(f"/api/images/{image_id}").status_code == 204


# ---------------------------------------------------------------- odd but valid images

def exif_rotated_jpeg() -> bytes:
    """A 64 x 48 px JPEG whose EXIF says: rotate 90° clockwise to display (Orientation 6)."""
    exif = Image.Exif()
    exif[0x0112] = 6
    return encode(Image.new("RGB", (64, 48), (90, 90, 90)), "JPEG", exif=exif)


def animated_gif() -> bytes:
    frames = [Image.new("L", (64, 48), level).convert("P") for level in (200, 30)]
    return encode(frames[0], "GIF", save_all=True, append_images=frames[1:], duration=100, loop=0)


ODD_IMAGES = {
    "16bit.png": (cv2.imencode(".png", np.random.default_rng(0).integers(0, 65535, (48, 64), np.uint16))[1]
                  .tobytes(), (64, 48)),
    "rgba.png": (encode(Image.new("RGBA", (64, 48), (200, 200, 200, 60)), "PNG"), (64, 48)),
    "gray.png": (encode(Image.new("L", (64, 48), 128), "PNG"), (64, 48)),
    "cmyk.jpg": (encode(Image.new("CMYK", (64, 48), (0, 200, 0, 0)), "JPEG"), (64, 48)),
    "one_pixel.jpg": (encode(Image.new("RGB", (1, 1), (255, 255, 255)), "JPEG"), (1, 1)),
    "strip.png": (encode(Image.new("L", (4000, 1), 255), "PNG"), (4000, 1)),
    # the assumed camera of a tall strip saw 180° down it, and the camera check refused its own assumption
    "tall_strip.png": (encode(Image.new("L", (1, 4000), 255), "PNG"), (1, 4000)),
    "black.jpg": (encode(Image.new("RGB", (640, 480)), "JPEG"), (640, 480)),
    "white.png": (encode(Image.new("RGB", (640, 480), (255, 255, 255)), "PNG"), (640, 480)),
    "animated.gif": (animated_gif(), (64, 48)),  # the first frame
    "rotated.jpg": (exif_rotated_jpeg(), (48, 64)),  # EXIF orientation applied: width and height swap
}


@pytest.mark.parametrize("name", ODD_IMAGES)
def test_odd_but_valid_images_get_a_result_and_every_figure(client, name):
    data, (width, height) = ODD_IMAGES[name]
    r = upload(client, (name, data, None))
    assert r.status_code == 201, r.text
    detail = processed(client, r.json()["images"][0]["id"])
    assert detail["status"] in ("none", "recognized") and detail["error"] is None, detail
    assert (detail["width"], detail["height"]) == (width, height)
    for stage in STAGES:
        figure = client.get(f"/api/images/{detail['id']}/stages/{stage}")
        if stage == "text" and detail["label"] is None:  # no sign, no text checked: the figure says why not
            assert_error(figure, 404, "no sign was recognised")
            continue
        assert figure.status_code == 200 and figure.headers["content-type"] == "image/png", (stage, figure.text)
    assert client.post("/api/recognize", files={"file": (name, data, "image/png")}).status_code == 200
    assert client.delete(f"/api/images/{detail['id']}").status_code == 204


@pytest.mark.parametrize("name", ["one_pixel.jpg", "gray.png"])
def test_small_images_are_drawn_enlarged_under_their_labels(client, name):
    """A 1 x 1 px image's input figure was one black pixel, its "no sign" label drawn over the whole
    photo, and the page stretched it into a large black square: small images are drawn enlarged."""
    data, (width, height) = ODD_IMAGES[name]
    detail = processed(client, upload(client, (name, data, None)).json()["images"][0]["id"])
    pixel = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)[0, 0]  # every pixel alike
    for stage, background in (("input", pixel), ("crop", pixel), ("blob", np.round(DIM * pixel))):
        r = client.get(f"/api/images/{detail['id']}/stages/{stage}")
        figure = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
        h, w = figure.shape[:2]
        assert max(h, w) >= MIN_SIDE_PX and h % height == 0 and h * width == w * height, (stage, figure.shape)
        colours, counts = np.unique(figure.reshape(-1, 3), axis=0, return_counts=True)
        assert np.array_equal(colours[counts.argmax()], background), stage  # mostly the photo, not labels
    assert has(cv2.imdecode(np.frombuffer(client.get(f"/api/images/{detail['id']}/stages/input").content,
                                                 np.uint8), cv2.IMREAD_COLOR), RED)  # "no sign", legible
    assert client.delete(f"/api/images/{detail['id']}").status_code == 204


# ---------------------------------------------------------------- names and ids that look like paths

HOSTILE_NAMES = [
    b"../../escape.jpg", b"/tmp/absolute.jpg", b"C:\\Windows\\system32\\evil.jpg", b"..\\..\\escape.jpg",
    b"\xff\xfe\xfd not utf-8.jpg", b"nul\x00byte.jpg", b"%2e%2e%2fencoded.jpg", b"a" * 1000 + b".jpg",
    b"\xd9\x85\xd8\xac\xd9\x85\xd8\xb9 \xd8\xa3\xd9\x85\xd9\x86\xd9\x8a.jpg",  # Arabic, as UTF-8
]


def test_client_file_names_are_labels_never_paths(client, base_url, root):
    before = outside_state(root)
    photo = sign_photo(LIBRARY, "chief_of_security")
    for filename in HOSTILE_NAMES:
        status, body = raw_post(base_url, "/api/images", *multipart(filename, photo))
        assert status == 201, (filename, body)
        name = body["images"][0]["name"]
        assert "/" not in name and "\\" not in name and "\x00" not in name and 0 < len(name) <= 200, name
    names = [i["name"] for i in client.get("/api/images").json()["images"]]
    assert names[0] == "escape.jpg" and names[-1] == "مجمع أمني.jpg"
    # Past the multipart parser's 4 KB header line: the form is refused whole, saying why.
    for path, field in (("/api/images", "files"), ("/api/recognize", "file"), ("/api/library", "file")):
        r = client.post(path, files={field: ("a" * 5000 + ".jpg", photo, "image/jpeg")})
        assert_error(r, 422, f"a file name longer than about {FILE_NAME_CHARS:,} characters", "shorter name")
    assert image_count(client) == len(names)
    longest = "a" * (FILE_NAME_CHARS - len(".jpg")) + ".jpg"  # the longest the message promises
    assert client.post("/api/recognize", files={"file": (longest, photo, "image/jpeg")}).status_code == 200
    images_dir = root / "state" / "images"
    assert sorted(p.name for p in images_dir.iterdir() if not STORED_NAME.match(p.name)) == ["index.json"]
    assert outside_state(root) == before and not Path("/tmp/absolute.jpg").exists()
    for image in client.get("/api/images").json()["images"]:
        assert client.delete(f"/api/images/{image['id']}").status_code == 204


def test_sign_ids_and_image_ids_that_look_like_paths(client, base_url, root):
    before = outside_state(root)
    library_files = sorted(p.name for p in (root / "state" / "library").iterdir())
    photo = sign_photo(LIBRARY, "ministry_of_torture")
    for sign_id in ("../escape", "/tmp/absolute", "a\x00b", "..", ".", "a/b", "x" * 65, "", "NUL", "a b"):
        r = client.post("/api/library", files={"file": ("s.jpg", photo, "image/jpeg")},
                        data={"id": sign_id, "width_m": "0.4", "height_m": "0.3"})
        assert r.status_code == 422, (sign_id, r.text)
    status, body = raw_post(base_url, "/api/library", *multipart(b"../../sign.png", photo, b"file"))
    assert status == 422  # no id, so no sign; the file name would never have been used anyway
    for path in ("/api/library/..%2F..%2Fsettings.json/image", "/api/library/%00/image", "/api/library/..",
                 "/api/library/%2Ftmp%2Fx/image"):
        assert client.get(path).status_code == 404, path
        assert client.delete(path.removesuffix("/image")).status_code in (404, 405), path
    for image_id in ("..%2Findex.json", "%2Fetc%2Fpasswd", "0123456789ab", "0123456789AB", "%00", "x" * 5000):
        for method, suffix in (("GET", ""), ("GET", "/file"), ("GET", "/stages/input"), ("DELETE", "")):
            r = client.request(method, f"/api/images/{image_id}{suffix}")
            assert r.status_code in (404, 405), (image_id, suffix, r.status_code)  # 405: the page's static files
        assert client.patch(f"/api/images/{image_id}", json={"expected": None}).status_code in (404, 405)
        assert client.post("/api/calibrate/threshold", json={"image_id": image_id}).status_code in (404, 422)
    assert sorted(p.name for p in (root / "state" / "library").iterdir()) == library_files
    assert outside_state(root) == before


# ---------------------------------------------------------------- settings and camera values

@pytest.mark.parametrize("body", [
    b'{"ransac_iterations": -5}', b'{"min_inliers": -1}', b'{"threshold": -0.5}', b'{"ratio": 1e999}',
    b'{"ransac_iterations": 1' + b"0" * 400 + b"}", b'{"ratio": true}', b'{"ratio": null}', b'{"ratio": {"x": 1}}',
    b'{"detector": ["sift"]}', b'{"detector": 7}', b'{"' + b"k" * 10_000 + b'": 1}', b'{"ratio": "0.7"}',
    b"\xff\xfe{}", b"", b"null", b'"threshold"', b'{"ratio": 0.7', b'{"ratio": NaN}', b'{"ratio": -Infinity}',
])
def test_bad_settings_change_nothing(client, body):
    before = client.get("/api/settings").json()
    r = client.put("/api/settings", content=body, headers={"content-type": "application/json"})
    assert 400 <= r.status_code < 500, r.text
    assert client.get("/api/settings").json() == before
    assert_error(client.post("/api/settings/import", files={"file": ("s.json", body, "application/json")}),
                 422)
    assert client.get("/api/settings").json() == before


DEEP = 100_000  # levels of nesting, far past what Python's json reads (its stack: some thousand)
UNREADABLE_JSON = {  # body: what the answer says
    b"[" * DEEP + b"]" * DEEP: "the body is JSON nested too deep to read (hundreds of levels)",
    b'{"a": ' * DEEP + b"1" + b"}" * DEEP: "the body is JSON nested too deep to read (hundreds of levels)",
    b'{"threshold": ' + b"1" * 5000 + b"}": "the body is JSON with a whole number of over 4300 digits",
    b'{"name": "\xff"}': "the body is not valid JSON: 'utf-8' codec can't decode byte 0xff",
}


def test_json_bodies_python_cannot_read_are_a_422_saying_why_on_every_route(client):
    """FastAPI answered a JSON body that json.loads cannot hold (nested deeper than its stack, a whole number
    of thousands of digits) or that is not UTF-8 with 400 "There was an error parsing the body", on every
    route whose body it reads; the server goes on serving (`client`)."""
    paths = client.get("/openapi.json").json()["paths"]
    routes = [(method, path.replace("{image_id}", "0" * 12)) for path, methods in paths.items()
              for method, operation in methods.items()
              if list(operation.get("requestBody", {}).get("content", {})) == ["application/json"]]
    assert len(routes) >= 7, routes
    for method, path in routes:
        for body, words in UNREADABLE_JSON.items():
            r = client.request(method, path, content=body, headers={"content-type": "application/json"})
            assert_error(r, 422, words)

CAMERA_FILES = {
    "zero_focal.yaml": (b"camera_matrix: {rows: 3, cols: 3, data: [0, 0, 320, 0, 0, 240, 0, 0, 1]}\n", "positive"),
    "negative_focal.json": (b'{"fx": -600, "fy": 600, "cx": 320, "cy": 240}', "positive"),
    "two_by_two.yaml": (b"camera_matrix: {rows: 2, cols: 2, data: [600, 0, 0, 600]}\n", "9 values"),
    "nan.json": (b'{"fx": NaN, "fy": 600, "cx": 320, "cy": 240}', "finite"),
    "skewed.yaml": (b"camera_matrix: {rows: 3, cols: 3, data: [600, 0, 320, 5, 600, 240, 0, 0, 1]}\n", "form"),
    "three_dist.json": (b'{"fx": 600, "fy": 600, "cx": 320, "cy": 240, "dist": [0.1, 0.2, 0.3]}', "distortion"),
    "binary.yaml": (bytes(range(256)), "binary.yaml"),
    "list.yaml": (b"- 1\n- 2\n", "list.yaml"),
}


@pytest.mark.parametrize("name", CAMERA_FILES)
def test_malformed_camera_files_change_nothing(client, name):
    data, word = CAMERA_FILES[name]
    before = client.get("/api/camera").json()
    assert_error(client.put("/api/camera", files={"file": (name, data, "application/octet-stream")}), 422, word)
    assert client.get("/api/camera").json() == before


@pytest.mark.parametrize("body", [
    {"fx": 0, "fy": 600, "cx": 320, "cy": 240}, {"fx": 600, "fy": 600, "cx": 320, "cy": 240, "width": -640},
    {"fx": 600, "fy": 600, "cx": 320}, {"fx": "600", "fy": [600], "cx": 320, "cy": 240},
    {"fx": 600, "fy": 600, "cx": 320, "cy": 240, "dist": "none"}, [600, 600, 320, 240],
    json.dumps({"fx": 600, "fy": 600, "cx": 320, "cy": 240}).encode()[:-1] + b', "x": "\xff\xfe"}', b"\xff\x4c",
])
def test_malformed_camera_json_changes_nothing(client, body):
    before = client.get("/api/camera").json()
    raw = body if isinstance(body, bytes) else json.dumps(body).encode()
    assert client.put("/api/camera", content=raw, headers={"content-type": "application/json"}).status_code == 422
    assert client.get("/api/camera").json() == before


# ---------------------------------------------------------------- references to what is gone

def test_deleting_a_sign_that_results_still_name(tmp_path):
    # Re-runs held off, so the results keep naming the deleted sign while every route is asked about them.
    config = WorkspaceConfig(state_dir=tmp_path / "state", load_samples=False, workers=1, debounce_s=3600,
                             max_wait_s=3600)
    with running(create_app(config)) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        r = upload(c, ("compound.jpg", sign_photo(LIBRARY, "security_compound"), "security_compound"))
        image_id = r.json()["images"][0]["id"]
        assert processed(c, image_id)["label"] == "security_compound"
        assert c.delete("/api/library/security_compound").status_code == 204
        detail = c.get(f"/api/images/{image_id}").json()
        assert detail["label"] == "security_compound" and detail["status"] == "pending"
        assert detail["expected"] == "security_compound"  # kept: the person may add the sign back
        for stage in STAGES:
            if stage == "text":  # the text check's figure needs the sign's template
                assert_error(c.get(f"/api/images/{image_id}/stages/{stage}"), 404, "no longer in the library")
                continue
            assert c.get(f"/api/images/{image_id}/stages/{stage}").status_code == 200, stage
        # The result's own matches against the deleted sign can still be drawn; a sign never known cannot.
        assert c.get(f"/api/images/{image_id}/stages/matches?sign=security_compound").status_code == 200
        assert_error(c.get(f"/api/images/{image_id}/stages/matches?sign=never_known"), 404, "not in the library")
        assert c.post("/api/calibrate/threshold", json={"image_id": image_id}).status_code == 200
        assert_error(c.patch(f"/api/images/{image_id}", json={"expected": "security_compound"}), 422,
                     "not a sign in the library")
        assert c.get("/api/sweep", params={"steps": 2}).json()["correct"] == [0, 0]  # it cannot be right now
        assert_error(c.get("/api/library/security_compound/image"), 404)
        assert c.get("/api/health").json()["status"] == "ok"
