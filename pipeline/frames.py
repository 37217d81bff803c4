"""Frame sources: a video file, a folder or list of images, a ROS 1 or ROS 2 bag, a live camera or a stream.

`open_source(spec)` picks the kind from `spec` and returns a `FrameSource`: an iterable of `Frame`s,
decoded one at a time (never the whole video in memory), with the source's `name`, its `camera` when
the source carries one (a bag's `sensor_msgs/CameraInfo`), `fps` and `count` when known. Everything a
user can fix (a missing file, a truncated video, a bag without images) is a `SourceError` of one line
that names the source.

Times: `Frame.time_s` is seconds from the first frame. Video files: index / fps (OpenCV's FFmpeg
backend reports CAP_PROP_POS_MSEC in decode order on videos with B-frames, e.g. 0, 101, 67, 134 ms,
so the container's nominal rate is the better clock); live cameras and streams: the monotonic clock
when each frame was read; image folders and lists: index / fps, with fps as given or one frame a
second; bags: the message header stamps (`Frame.stamp_ns`, nanoseconds since the epoch), or the
time each message was recorded when the header stamps are zero.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Iterator, Sequence
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .camera import OPENCV_DISTORTION_MODELS, Camera, CameraError, camera_from_json
from .image import ImageError, check_image_header, decode_image, decoders_kept_quiet, read_file

# The largest frame read, as for photos (app.workspace.WorkspaceConfig.max_pixels).
DEFAULT_MAX_PIXELS = 40_000_000
VIDEO_SUFFIXES = frozenset([".mp4", ".m4v", ".avi", ".mkv", ".mov", ".webm", ".mpg", ".mpeg", ".wmv", ".flv", ".ts"])
IMAGE_SUFFIXES = frozenset([".jpg", ".jpeg", ".png", ".tif", ".tiff", ".webp", ".bmp", ".gif"])
ROS2_SUFFIXES = frozenset([".mcap", ".db3"])
ROS1_SUFFIX = ".bag"
STREAM_SCHEMES = ("rtsp://", "rtsps://", "http://", "https://", "rtmp://", "udp://", "tcp://")
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
# Image frames' time step when no rate is given: one frame a second, so time_s counts frames.
DEFAULT_IMAGE_FPS = 1.0
# A video may end a frame or two before the count its container gives (box.mp4 lists 456 frames and
# decodes 455); ending more than this fraction short is a file cut short or damaged.
TRUNCATED_FRACTION = 0.01
# sensor_msgs/Image encodings: channels, bytes per channel, and the OpenCV conversion to BGR (None: none needed).
_ENCODINGS: dict[str, tuple[int, int, int | None]] = {
    "mono8": (1, 1, None), "8UC1": (1, 1, None), "mono16": (1, 2, None), "16UC1": (1, 2, None),
    "bgr8": (3, 1, None), "8UC3": (3, 1, None), "rgb8": (3, 1, cv2.COLOR_RGB2BGR),
    "bgra8": (4, 1, cv2.COLOR_BGRA2BGR), "8UC4": (4, 1, cv2.COLOR_BGRA2BGR), "rgba8": (4, 1, cv2.COLOR_RGBA2BGR),
    # ROS names the Bayer pattern from the top-left pixel, OpenCV from the second row's second pixel.
    "bayer_rggb8": (1, 1, cv2.COLOR_BayerBG2BGR), "bayer_bggr8": (1, 1, cv2.COLOR_BayerRG2BGR),
    "bayer_gbrg8": (1, 1, cv2.COLOR_BayerGR2BGR), "bayer_grbg8": (1, 1, cv2.COLOR_BayerGB2BGR),
}

# Video containers by their first bytes, to say which kind of file could not be opened.
_CONTAINERS = {
    "MP4/MOV": lambda head: head[4:8] in (b"ftyp", b"moov", b"mdat", b"free", b"wide"),
    "AVI": lambda head: head[:4] == b"RIFF" and head[8:12] == b"AVI ",
    "Matroska/WebM": lambda head: head[:4] == b"\x1aE\xdf\xa3",
}


class SourceError(ValueError):
    """A source that cannot be read: one line naming it and saying what is wrong."""


@dataclass(frozen=True, eq=False)
class Frame:
    """One frame: `index` from 0, `time_s` seconds from the first frame, `image` (H, W, 3) uint8 BGR or
    (H, W) uint8 gray, `stamp_ns` the source's own time (ns since the epoch) when it has one (bags)."""

    index: int
    time_s: float
    image: np.ndarray
    stamp_ns: int | None = None


class FrameSource:
    """Frames of one source, read as they are iterated; a context manager that `close()`s it.

    `name`: the source as given. `camera`: intrinsics the source carries (a bag's CameraInfo), else None.
    `fps`: its nominal frame rate, None when not known. `count`: how many frames it holds when known
    (for a progress bar), else None. `warnings`: what the source noticed and the caller should show.
    Videos, cameras and streams are iterated once; image files and bags can be read again.
    """

    def __init__(self, name: str, *, camera: Camera | None = None, fps: float | None = None,
                 count: int | None = None, max_pixels: int = DEFAULT_MAX_PIXELS) -> None:
        self.name = name
        self.camera = camera
        self.fps = fps
        self.count = count
        self.max_pixels = max_pixels
        self.warnings: list[str] = []

    def __iter__(self) -> Iterator[Frame]:
        raise NotImplementedError

    def frames_from(self, start: int) -> Iterator[Frame]:
        """The frames from index `start` on, instead of iterating the source: those before it are read and
        dropped, unless the source can go to `start` directly (a video file, image files, a bag's messages)."""
        return (frame for frame in self if frame.index >= start)

    def close(self) -> None:
        """Release what the source holds open; iterating afterwards is an error."""

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def check_size(self, width: int, height: int, what: str) -> None:
        """SourceError when a `width` x `height` px frame (`what`: which one) is over `max_pixels`."""
        if width * height > self.max_pixels:
            raise SourceError(f"{self.name}: {what} is {width}x{height} px, {width * height / 1e6:.1f} megapixels, "
                              f"more than the {self.max_pixels / 1e6:g} megapixels allowed")


def natural_key(name: str) -> tuple[Any, ...]:
    """Sort key putting "frame2" before "frame10": digit runs compare as numbers, the rest case-blind."""
    return tuple(int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name))


def unused_options(source: FrameSource, *, topic: str | None, fps: float | None) -> str | None:
    """Why `topic` or `fps`, given for `source` alone, has no use there (a topic is a bag's; a video has its own
    rate, a bag its stamps), None when each given has: for a caller to say rather than ignore. A command over
    several sources of several kinds gives them to the bags or the images among them."""
    if topic is not None and not isinstance(source, BagSource):
        return f"{source.name} is not a ROS bag, so it has no topic {topic}"
    if fps is not None and not isinstance(source, ImageSource):
        timed = "its own frame rate" if isinstance(source, VideoSource) else "its stamps"
        return f"{source.name} is timed by {timed}; a frame rate is given to a folder or list of images"
    return None


def open_source(spec: str | Path | Sequence[str | Path], *, topic: str | None = None, fps: float | None = None,
                max_pixels: int = DEFAULT_MAX_PIXELS) -> FrameSource:
    """The `FrameSource` `spec` names: `camera:N` (a live camera), a stream URL (rtsp://, http://, ...), a
    video file, a ROS 2 bag (`.mcap`/`.db3` file, or a rosbag2 folder with metadata.yaml), a ROS 1 `.bag`,
    a folder of images (natural sort order), an image file, or a sequence of image files (each a frame).

    `topic`: a bag's image topic (default: its only one). `fps`: the rate of image frames (default one a
    second); ignored by the other kinds, which know their own (`unused_options` says so for a source given
    alone). SourceError for what cannot be read.
    """
    if not isinstance(spec, (str, Path)):
        paths = [Path(p) for p in spec]
        if len(paths) == 1:
            return open_source(paths[0], topic=topic, fps=fps, max_pixels=max_pixels)
        return ImageSource(_image_list(paths), name=f"{paths[0]} .. ({len(paths)} images)" if paths else "",
                           fps=fps, max_pixels=max_pixels)
    text = str(spec)
    if text.startswith("camera:"):
        index = text.removeprefix("camera:")
        if not index.isdigit():
            raise SourceError(f"{text}: a live camera is camera:N, N its index (camera:0 the first)")
        return VideoSource(text, device=int(index), max_pixels=max_pixels)
    if text.lower().startswith(STREAM_SCHEMES):
        return VideoSource(text, live=True, max_pixels=max_pixels)
    path = Path(spec)
    if not path.exists():
        raise SourceError(f"{path}: no such file or folder")
    suffix = path.suffix.lower()
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return BagSource(path, topic=topic, max_pixels=max_pixels)
        return ImageSource(_image_folder(path), name=str(path), fps=fps, max_pixels=max_pixels)
    if suffix in ROS2_SUFFIXES or suffix == ROS1_SUFFIX:
        return BagSource(path, topic=topic, max_pixels=max_pixels)
    if suffix in VIDEO_SUFFIXES:
        return VideoSource(str(path), max_pixels=max_pixels)
    if suffix in IMAGE_SUFFIXES:
        return ImageSource([path], name=str(path), fps=fps, max_pixels=max_pixels)
    raise SourceError(f"{path}: unknown kind of source {suffix or '(no extension)'}: expected a video "
                      f"({', '.join(sorted(VIDEO_SUFFIXES))}), a ROS bag (.mcap, .db3, .bag, or a rosbag2 folder), "
                      "a folder of images or image files, camera:N, or a stream URL")


def _image_folder(folder: Path) -> list[Path]:
    """The image files directly in `folder`, in natural sort order; SourceError when there are none."""
    images = sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()),
                    key=lambda p: natural_key(p.name))
    if not images:
        raise SourceError(f"{folder}: no image files ({', '.join(sorted(IMAGE_SUFFIXES))}) in this folder, and no "
                          "metadata.yaml (a rosbag2 folder)")
    return images


def _image_list(paths: list[Path]) -> list[Path]:
    """`paths` as given, after checking that each is an existing image file; SourceError naming the first that is not."""
    if not paths:
        raise SourceError("no source given")
    for path in paths:
        if not path.is_file():
            raise SourceError(f"{path}: no such file" if not path.exists() else
                              f"{path}: a folder in a list of image files: give a folder alone")
        if path.suffix.lower() not in IMAGE_SUFFIXES:
            raise SourceError(f"{path}: not an image file ({', '.join(sorted(IMAGE_SUFFIXES))}); several sources are "
                              "image files, each a frame: give a video or a bag alone")
    return paths


class ImageSource(FrameSource):
    """Image files, each a frame, in the order given; time_s = index / fps (fps given, else DEFAULT_IMAGE_FPS).
    Every frame must have the first one's size."""

    def __init__(self, paths: list[Path], *, name: str, fps: float | None, max_pixels: int) -> None:
        if fps is not None and not (math.isfinite(fps) and fps > 0):
            raise SourceError(f"{name}: the frame rate must be a positive number of frames a second; got {fps}")
        super().__init__(name, fps=fps, count=len(paths), max_pixels=max_pixels)
        self.paths = paths

    def __iter__(self) -> Iterator[Frame]:
        return self.frames_from(0)

    def frames_from(self, start: int) -> Iterator[Frame]:
        """The frames from index `start` on; the files before it are not read."""
        step = 1.0 / (self.fps or DEFAULT_IMAGE_FPS)
        first: tuple[int, int] | None = None
        for index, path in enumerate(self.paths[start:], start):
            try:
                data = read_file(path)
                # The header's size, before decoding: a small file can claim gigabytes of pixels.
                check_image_header(data, f"{self.name}: frame {index} ({path.name})", self.max_pixels)
                image = decode_image(data, str(path))
            except ImageError as exc:
                raise SourceError(str(exc)) from None
            height, width = image.shape[:2]
            if first is None:
                first = (width, height)
            elif (width, height) != first:
                raise SourceError(f"{self.name}: frame {index} ({path.name}) is {width}x{height} px, the first "
                                  f"{first[0]}x{first[1]} px: the frames of one sequence share one size")
            yield Frame(index, index * step, image)


class VideoSource(FrameSource):
    """A video file, a live camera (`device`) or a stream URL (`live`), through cv2.VideoCapture with
    OpenCV's bundled FFmpeg. A file is checked when opened: it opens, and its first frame decodes."""

    def __init__(self, name: str, *, device: int | None = None, live: bool = False, max_pixels: int) -> None:
        super().__init__(name, max_pixels=max_pixels)
        self.live = live or device is not None
        with self._quiet():
            self.capture = cv2.VideoCapture(device if device is not None else name)
        if not self.capture.isOpened():
            self.capture.release()
            if device is not None:
                raise SourceError(f"{name}: cannot open camera {device} (no such camera, or it is in use)")
            if self.live:
                raise SourceError(f"{name}: cannot open the stream (unreachable, refused, or not a video stream)")
            raise SourceError(f"{name}: {_unopened_video(Path(name))}")
        fps = self.capture.get(cv2.CAP_PROP_FPS)
        self.fps = fps if math.isfinite(fps) and fps > 0 else None
        count = self.capture.get(cv2.CAP_PROP_FRAME_COUNT)
        self.count = int(count) if not self.live and math.isfinite(count) and count > 0 else None
        width, height = (int(self.capture.get(p)) for p in (cv2.CAP_PROP_FRAME_WIDTH, cv2.CAP_PROP_FRAME_HEIGHT))
        # Until a refused file is released: FFmpeg's decoder threads log the frames they drop meanwhile.
        with self._quiet():
            try:
                self.check_size(width, height, "each frame")
                ok, first = self.capture.read()
                if not ok or first is None:
                    raise SourceError(f"{name}: {'no frame arrives' if self.live else 'opens but no frame decodes'} "
                                      f"(codec {self.codec()!r}: one OpenCV's FFmpeg cannot decode, or the data is "
                                      "corrupt)")
            except SourceError:
                self.capture.release()
                raise
        self.first: np.ndarray | None = first
        self.first_clock = time.monotonic()

    def _quiet(self) -> AbstractContextManager[None]:
        """FFmpeg's log kept off stderr while a file is opened and checked: why it is refused ("moov atom
        not found") is said in signpose's words. A live source's log is kept: it names the refusal."""
        return nullcontext() if self.live else decoders_kept_quiet()

    def codec(self) -> str:
        """The stream's FourCC as text ("avc1", "mp4v", ...), "unknown" when OpenCV gives none."""
        code = int(self.capture.get(cv2.CAP_PROP_FOURCC))
        text = "".join(chr((code >> (8 * i)) & 0xFF) for i in range(4))
        return text if code and text.isprintable() else "unknown"

    def __iter__(self) -> Iterator[Frame]:
        if self.first is None:
            raise SourceError(f"{self.name}: a video is read once")
        image, self.first = self.first, None
        yield from self._frames(0, image)

    def frames_from(self, start: int) -> Iterator[Frame]:
        """The frames from index `start` on. A file seeks there: FFmpeg decodes from the keyframe before it, so
        the frames are those a read from the start gives (checked on the sample flight and on a real
        hand-held H.264 video) at the cost of one group of pictures, not of every frame before `start`."""
        if start == 0 or self.live or self.first is None or not self.capture.set(cv2.CAP_PROP_POS_FRAMES, start):
            return super().frames_from(start)
        self.first = None
        ok, image = self.capture.read()
        return self._frames(start, image if ok else None)

    def _frames(self, index: int, image: np.ndarray | None) -> Iterator[Frame]:
        """Frame `index`, whose `image` is read, and those after it; SourceError at the end when the frames end
        well before the count the container lists."""
        while image is not None:
            if self.live:
                time_s = time.monotonic() - self.first_clock if index else 0.0
            else:
                time_s = index / (self.fps or DEFAULT_IMAGE_FPS)
            yield Frame(index, time_s, image)
            index += 1
            ok, image = self.capture.read()
            if not ok:
                image = None
        if self.count is not None and index < self.count * (1 - TRUNCATED_FRACTION) - 1:
            raise SourceError(f"{self.name}: frames end at {index} of the {self.count} its container lists: the file "
                              "is truncated or corrupt")

    def close(self) -> None:
        self.capture.release()


def _unopened_video(path: Path) -> str:
    """Why OpenCV could not open the video file `path`, by the container its first bytes name (FFmpeg refuses
    a file it has no decoder for as it refuses a damaged one: they cannot be told apart from OpenCV)."""
    try:
        with path.open("rb") as file:
            head = file.read(12)
    except OSError as exc:
        return f"cannot be read: {exc.strerror or exc}"
    container = next((kind for kind, test in _CONTAINERS.items() if test(head)), None)
    if container is None:
        return "not a video file OpenCV's FFmpeg reads (or one truncated or corrupt)"
    return (f"OpenCV's FFmpeg cannot open this {container} file: truncated, corrupt, or in a codec it cannot decode "
            "(re-encode it as H.264)")


class BagSource(FrameSource):
    """sensor_msgs Image or CompressedImage messages on one topic of a ROS 2 bag (`.mcap`, `.db3`, or a
    rosbag2 folder) or a ROS 1 `.bag`, read with `rosbags` (no ROS install). The camera comes from the
    first CameraInfo message on `<namespace>/camera_info` of the image topic or of a namespace above it
    (/cam/image_raw/compressed: /cam/image_raw/camera_info, then /cam/camera_info)."""

    def __init__(self, path: Path, *, topic: str | None, max_pixels: int) -> None:
        from rosbags.highlevel import AnyReader, AnyReaderError
        from rosbags.typesys import Stores, get_typestore

        super().__init__(str(path), max_pixels=max_pixels)
        self.bits_16 = 8  # the most bits a 16-bit image of the stream has used yet, 8 at least
        self.reader_error = AnyReaderError
        # Bags without message definitions (rosbag2 before Iron) are read with Humble's.
        self.reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        try:
            self.reader.open()
        except (AnyReaderError, OSError, ValueError, KeyError) as exc:
            # A recording cut short (a full disk, a crash) has no index: the bag tools rebuild one.
            fix = {".mcap": "; if the recording was cut short, `mcap recover` writes a readable copy",
                   ROS1_SUFFIX: "; if the recording was cut short, `rosbag reindex` repairs it"}.get(path.suffix.lower(), "")
            raise SourceError(f"{path}: cannot be read as a ROS bag: {exc}{fix}") from None
        try:
            self.connection = self._image_connection(topic)
            self.topic: str = self.connection.topic
            self.count = sum(c.msgcount for c in self.reader.connections if c.topic == self.topic) or None
            self.camera = self._camera()
        except SourceError:
            self.reader.close()
            raise

    def _image_connection(self, topic: str | None) -> Any:
        """The connection of `topic`, or of the bag's only image topic; SourceError naming the topics otherwise."""
        connections = self.reader.connections
        images = sorted({c.topic for c in connections if c.msgtype in IMAGE_TYPES})
        topics = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in connections})) or "none"
        if topic is None:
            if not images:
                raise SourceError(f"{self.name}: the bag has no image topics (sensor_msgs/Image or CompressedImage); "
                                  f"its topics: {topics}")
            if len(images) > 1:
                raise SourceError(f"{self.name}: the bag has several image topics ({', '.join(images)}): choose one "
                                  "with --topic")
            topic = images[0]
        found = [c for c in connections if c.topic == topic]
        if not found:
            raise SourceError(f"{self.name}: no topic {topic} in the bag; its image topics: {', '.join(images) or 'none'}")
        if found[0].msgtype not in IMAGE_TYPES:
            raise SourceError(f"{self.name}: topic {topic} carries {found[0].msgtype}, not images; its image topics: "
                              f"{', '.join(images) or 'none'}")
        return found[0]

    def _camera(self) -> Camera | None:
        """The camera of the first CameraInfo in the image topic's namespace, None (with a warning when one is
        there but unusable) otherwise."""
        infos = {c.topic: c for c in self.reader.connections if c.msgtype == CAMERA_INFO_TYPE}
        parts = self.topic.strip("/").split("/")
        for depth in range(len(parts) - 1, -1, -1):
            name = "/" + "/".join([*parts[:depth], "camera_info"])
            if name not in infos:
                continue
            for connection, _, raw in self.reader.messages(connections=[infos[name]]):
                fields = _camera_info_fields(self.reader.deserialize(raw, connection.msgtype))
                # What drivers publish for an image without distortion, or one whose lens nobody calibrated:
                # its K is still nearer the truth than an assumed field of view.
                no_coefficients = (not fields.get("d", fields.get("D"))
                                   and fields["distortion_model"].lower() in OPENCV_DISTORTION_MODELS)
                if no_coefficients:
                    fields["distortion_model"] = "none"
                try:
                    camera = camera_from_json(fields, source=f"{self.name} {name}")
                except CameraError as exc:
                    self.warnings.append(f"{self.name}: the CameraInfo on {name} is not used: {exc}")
                    return None
                if no_coefficients:
                    self.warnings.append(f"{self.name}: the CameraInfo on {name} gives no distortion coefficients: "
                                         "the lens is taken as without distortion; give a camera file for one with")
                return camera
        return None

    def __iter__(self) -> Iterator[Frame]:
        return self.frames_from(0)

    def frames_from(self, start: int) -> Iterator[Frame]:
        """The frames from message `start` on; the messages before it are read from the bag, and not decoded
        (the first gives the stamp that times count from)."""
        first_ns: int | None = None
        header_stamps = True
        messages = self.reader.messages(connections=[c for c in self.reader.connections if c.topic == self.topic])
        for index, (connection, logged_ns, raw) in enumerate(messages):
            if index < start and first_ns is not None:
                continue
            try:
                msg: Any = self.reader.deserialize(raw, connection.msgtype)
            except self.reader_error as exc:
                raise SourceError(f"{self.name}: message {index} on {self.topic} cannot be read: {exc}") from None
            stamp = msg.header.stamp
            stamp_ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
            if first_ns is None:
                header_stamps = stamp_ns != 0  # drivers that leave the stamp unset: the recording time instead
            if not header_stamps:
                stamp_ns = int(logged_ns)
            if first_ns is None:
                first_ns = stamp_ns
            if index < start:
                continue
            where = f"message {index} on {self.topic}"
            if connection.msgtype == "sensor_msgs/msg/CompressedImage":
                image = self._decompressed(msg, where)
            else:
                self.check_size(int(msg.width), int(msg.height), where)
                image = self._raw_image(msg, where)
            yield Frame(index, (stamp_ns - first_ns) / 1e9, image, stamp_ns)

    def _decompressed(self, msg: Any, where: str) -> np.ndarray:
        """The BGR image of a CompressedImage message; SourceError naming `where` when it does not decode."""
        if "compresseddepth" in str(msg.format).lower():
            raise SourceError(f"{self.name}: {where} is a compressed depth image ({msg.format}), not a camera image")
        try:
            image = decode_image(bytes(msg.data), f"{self.name}: {where}")
        except ImageError as exc:
            raise SourceError(str(exc)) from None
        self.check_size(image.shape[1], image.shape[0], where)
        return image

    def _raw_image(self, msg: Any, where: str) -> np.ndarray:
        """The (H, W, 3) BGR or (H, W) gray uint8 image of an Image message."""
        encoding = str(msg.encoding)
        if encoding not in _ENCODINGS:
            raise SourceError(f"{self.name}: {where} has encoding {encoding!r}; readable: {', '.join(_ENCODINGS)}")
        channels, depth, conversion = _ENCODINGS[encoding]
        height, width, step = int(msg.height), int(msg.width), int(msg.step)
        data = np.asarray(msg.data, dtype=np.uint8)
        if step < width * channels * depth or data.size < step * height:
            raise SourceError(f"{self.name}: {where} holds {data.size} bytes, too few for {width}x{height} px "
                              f"{encoding} with rows of {step} bytes")
        rows = data[:step * height].reshape(height, step)[:, :width * channels * depth]
        if depth == 2:
            order = ">" if msg.is_bigendian else "<"
            wide = rows.copy().view(np.dtype(f"{order}u2")).astype(np.uint16)
            # Shifted down by the bits the stream has used so far beyond 8 (10- and 12-bit cameras keep their
            # levels, as `to_8bit` keeps a photo's), never fewer than before: a dark frame stays dark.
            self.bits_16 = max(self.bits_16, int(wide.max()).bit_length())
            pixels = (wide >> (self.bits_16 - 8)).astype(np.uint8)
        else:
            pixels = rows
        image = pixels.reshape(height, width, channels) if channels > 1 else pixels.reshape(height, width)
        return cv2.cvtColor(image, conversion) if conversion is not None else np.ascontiguousarray(image)

    def close(self) -> None:
        self.reader.close()


def _camera_info_fields(info: Any) -> dict[str, Any]:
    """A CameraInfo message (ROS 2's k, d or ROS 1's K, D) as the fields `camera_from_json` reads."""
    # A zero size is CameraInfo's "not set": the camera is then of no known size.
    size = {"width": int(info.width), "height": int(info.height)} if info.width and info.height else {}
    fields: dict[str, Any] = {**size, "distortion_model": str(info.distortion_model),
                              "binning_x": int(info.binning_x), "binning_y": int(info.binning_y)}
    for key in ("k", "K", "d", "D"):
        value = getattr(info, key, None)
        if value is not None:
            fields[key] = [float(v) for v in value]
    roi = info.roi
    fields["roi"] = {"x_offset": int(roi.x_offset), "y_offset": int(roi.y_offset), "width": int(roi.width),
                     "height": int(roi.height), "do_rectify": bool(roi.do_rectify)}
    return fields
