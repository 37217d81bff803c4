"""Frame sources (pipeline/frames.py): every kind of source, and a clear one-line error for each bad input."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin

from signpose.pipeline.frames import Frame, SourceError, natural_key, open_source, unused_options
from tests.support.bags import ROS1, ROS2, header, write_bag1, write_bag2, write_mcap
from tests.support.shared_data import shared_folder

BOX = shared_folder() / "data" / "video" / "box.mp4"
W, H = 32, 24
K = [100.0, 0.0, 16.0, 0.0, 100.0, 12.0, 0.0, 0.0, 1.0]
D = [0.1, -0.05, 0.0, 0.0, 0.0]
T0 = 1_700_000_000_000_000_000  # ns: the first frame's header stamp


def _frame(i: int) -> np.ndarray:
    """(H, W, 3) BGR test frame i: blue 10 i, green 100, red 200, so channel order and frame order both show."""
    image = np.zeros((H, W, 3), np.uint8)
    image[..., 0], image[..., 1], image[..., 2] = 10 * i, 100, 200
    return image


def _collect(spec, **kwargs) -> tuple[list[Frame], object]:
    with open_source(spec, **kwargs) as source:
        return list(source), source


def _error(spec, **kwargs) -> str:
    with pytest.raises(SourceError) as info:
        with open_source(spec, **kwargs) as source:
            list(source)
    message = str(info.value)
    assert "\n" not in message
    return message


# --- bags written here: one message dict per frame, made into each format's messages -------------------------

def _image_msg(store, i: int, encoding: str, stamp_ns: int, ros1: bool = False):
    bgr = _frame(i)
    pixels = {"bgr8": bgr, "rgb8": bgr[..., ::-1], "bgra8": np.dstack([bgr, np.full((H, W), 7, np.uint8)]),
              "rgba8": np.dstack([bgr[..., ::-1], np.full((H, W), 7, np.uint8)]),
              "mono8": np.full((H, W), 10 * i, np.uint8), "mono16": np.full((H, W), 2560 * i + 100, np.uint16)}[encoding]
    step = pixels.shape[1] * (pixels.shape[2] if pixels.ndim == 3 else 1) * pixels.itemsize
    return store.types["sensor_msgs/msg/Image"](
        header=header(store, stamp_ns, ros1), height=H, width=W, encoding=encoding, is_bigendian=0, step=step,
        data=np.frombuffer(pixels.astype(pixels.dtype.newbyteorder("<")).tobytes(), np.uint8))


def _compressed_msg(store, i: int, stamp_ns: int, ros1: bool = False):
    ok, png = cv2.imencode(".png", _frame(i))
    return store.types["sensor_msgs/msg/CompressedImage"](header=header(store, stamp_ns, ros1), format="png",
                                                          data=np.frombuffer(png.tobytes(), np.uint8))


def _info_msg(store, ros1: bool = False, k: list[float] = K):
    RegionOfInterest = store.types["sensor_msgs/msg/RegionOfInterest"]
    roi = RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    fields = {"D": np.array(D), "K": np.array(k), "R": np.eye(3).ravel(), "P": np.zeros(12)}
    if not ros1:
        fields = {key.lower(): value for key, value in fields.items()}
    return store.types["sensor_msgs/msg/CameraInfo"](
        header=header(store, T0, ros1), height=H, width=W, distortion_model="plumb_bob", binning_x=0, binning_y=0,
        roi=roi, **fields)


def _stamps(n: int) -> list[int]:
    return [T0 + i * 50_000_000 for i in range(n)]  # 20 fps


def _assert_frames(frames: list[Frame], n: int, stamps: list[int]) -> None:
    assert [f.index for f in frames] == list(range(n))
    assert [f.stamp_ns for f in frames] == stamps
    np.testing.assert_allclose([f.time_s for f in frames], [(s - stamps[0]) / 1e9 for s in stamps])
    for i, frame in enumerate(frames):
        assert frame.image.dtype == np.uint8 and frame.image.shape == (H, W, 3)
        np.testing.assert_array_equal(frame.image, _frame(i))


# --- image folders and lists ----------------------------------------------------------------------------------

def test_natural_sort_puts_frame2_before_frame10():
    names = ["frame10.png", "Frame2.png", "frame1.png", "frame1b.png"]
    assert sorted(names, key=natural_key) == ["frame1.png", "frame1b.png", "Frame2.png", "frame10.png"]


def test_a_folder_of_images_is_read_in_natural_order_at_one_frame_a_second(tmp_path):
    for i in (10, 2, 1):
        cv2.imwrite(str(tmp_path / f"frame{i}.png"), _frame(i))
    (tmp_path / "notes.txt").write_text("not a frame")
    frames, source = _collect(tmp_path)
    assert source.count == 3 and source.fps is None and source.camera is None and source.name == str(tmp_path)
    assert [f.time_s for f in frames] == [0.0, 1.0, 2.0] and all(f.stamp_ns is None for f in frames)
    assert [int(f.image[0, 0, 0]) for f in frames] == [10, 20, 100]


def test_a_list_of_images_keeps_its_order_and_takes_the_rate_given(tmp_path):
    paths = []
    for i in (3, 1):
        paths.append(tmp_path / f"f{i}.png")
        cv2.imwrite(str(paths[-1]), _frame(i))
    frames, source = _collect([str(p) for p in paths], fps=10.0)
    assert source.fps == 10.0 and source.count == 2
    assert [f.time_s for f in frames] == [0.0, 0.1]
    assert [int(f.image[0, 0, 0]) for f in frames] == [30, 10]
    single, _ = _collect(paths[0])
    assert len(single) == 1


def test_bad_image_sequences_are_refused_with_a_clear_message(tmp_path):
    (tmp_path / "empty").mkdir()
    assert "no image files" in _error(tmp_path / "empty")
    cv2.imwrite(str(tmp_path / "a1.png"), _frame(1))
    cv2.imwrite(str(tmp_path / "a2.png"), np.zeros((10, 10, 3), np.uint8))
    message = _error([tmp_path / "a1.png", tmp_path / "a2.png"])
    assert "frame 1 (a2.png) is 10x10 px, the first 32x24 px" in message
    assert "a3.png: no such file" in _error([tmp_path / "a1.png", tmp_path / "a3.png"])
    (tmp_path / "clip.mp4").write_bytes(b"x")
    assert "clip.mp4: not an image file" in _error([tmp_path / "a1.png", tmp_path / "clip.mp4"])
    (tmp_path / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 20)
    assert "broken.png" in _error([tmp_path / "a1.png", tmp_path / "broken.png"])
    assert "a1.png): 32x24 px is 0.0 megapixels, more than the limit of 0.0001" in _error(tmp_path / "a1.png",
                                                                                         max_pixels=100)
    assert "frame rate must be a positive number" in _error(tmp_path / "a1.png", fps=0.0)


def test_a_huge_image_frame_is_refused_from_its_header_without_decoding(tmp_path, monkeypatch):
    # A 200-byte PNG whose header claims 60000 x 60000 px (3.6 gigapixels, 10 GB decoded).
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", 60000, 60000, 8, 2, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")
    cv2.imwrite(str(tmp_path / "f1.png"), _frame(1))
    (tmp_path / "f2.png").write_bytes(png)

    def no_decoding(data: bytes, name: str = "image", as_stored: bool = False) -> np.ndarray:
        assert data != png, "the huge frame was handed to the decoder"
        return _frame(1)

    monkeypatch.setattr("signpose.pipeline.frames.decode_image", no_decoding)
    message = _error(tmp_path)
    assert "frame 1 (f2.png): 60000x60000 px is 3600.0 megapixels" in message, message


def test_missing_and_unknown_sources_are_named(tmp_path):
    assert _error(tmp_path / "nope.mp4") == f"{tmp_path / 'nope.mp4'}: no such file or folder"
    (tmp_path / "flight.txt").write_text("hello")
    message = _error(tmp_path / "flight.txt")
    assert message.startswith(f"{tmp_path / 'flight.txt'}: unknown kind of source .txt") and ".mp4" in message


# --- video -----------------------------------------------------------------------------------------------------

def _write_mp4(path: Path, n: int = 5, fps: float = 10.0) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (64, 48))
    for i in range(n):
        writer.write(np.full((48, 64, 3), 40 * i, np.uint8))
    writer.release()
    return path


def test_a_video_written_here_is_read_frame_by_frame_with_times_from_its_rate(tmp_path):
    frames, source = _collect(_write_mp4(tmp_path / "clip.mp4"))
    assert source.fps == pytest.approx(10.0) and source.count == 5 and source.camera is None
    assert [f.index for f in frames] == list(range(5))
    np.testing.assert_allclose([f.time_s for f in frames], [0.0, 0.1, 0.2, 0.3, 0.4])
    assert all(f.image.shape == (48, 64, 3) and f.image.dtype == np.uint8 for f in frames)
    assert np.all(np.diff([f.image.mean() for f in frames]) > 30)


@pytest.mark.skipif(not BOX.exists(), reason="shared data (box.mp4) not found: set SIGNPOSE_SHARED")
def test_real_footage_opens_with_its_count_and_rate():
    with open_source(str(BOX)) as source:
        assert source.count == 456 and source.fps == pytest.approx(29.97, abs=0.01)
        first = [frame for frame, _ in zip(source, range(3))]
    assert [f.image.shape for f in first] == [(480, 640, 3)] * 3
    np.testing.assert_allclose([f.time_s for f in first], np.arange(3) / source.fps)


@pytest.mark.skipif(not BOX.exists(), reason="shared data (box.mp4) not found: set SIGNPOSE_SHARED")
def test_real_footage_cut_short_reads_what_is_there_then_says_it_is_truncated(tmp_path):
    cut = tmp_path / "box_cut.mp4"
    cut.write_bytes(BOX.read_bytes()[:BOX.stat().st_size // 10])
    read = []
    with pytest.raises(SourceError) as info:
        with open_source(cut) as source:
            read.extend(source)
    assert 10 < len(read) < 100
    assert str(info.value) == f"{cut}: frames end at {len(read)} of the 456 its container lists: the file is truncated or corrupt"


def test_a_truncated_or_corrupt_video_is_refused_when_opened(tmp_path, capfd):
    """Each in signpose's words alone: FFmpeg's own log of it ("[mov,mp4,m4a,3gp,3g2,mj2 @ 0x55d0c1a2b3c0] moov
    atom not found") was printed above them."""
    data = _write_mp4(tmp_path / "clip.mp4").read_bytes()
    (tmp_path / "cut.mp4").write_bytes(data[:len(data) // 2])  # mp4v puts its index (moov) last: it is lost
    assert _error(tmp_path / "cut.mp4") == (f"{tmp_path / 'cut.mp4'}: OpenCV's FFmpeg cannot open this MP4/MOV file: "
                                            "truncated, corrupt, or in a codec it cannot decode (re-encode it as H.264)")
    (tmp_path / "text.mp4").write_text("not a video at all")
    assert _error(tmp_path / "text.mp4") == (f"{tmp_path / 'text.mp4'}: not a video file OpenCV's FFmpeg reads (or one "
                                             "truncated or corrupt)")
    assert "each frame is 64x48 px" in _error(tmp_path / "clip.mp4", max_pixels=1000)
    damaged = bytearray(data)
    start, end = damaged.find(b"mdat") + 4, damaged.find(b"moov") - 4
    damaged[start:end] = bytes(end - start)  # its frames' data zeros, its index (moov, last) whole
    (tmp_path / "zeroed.mp4").write_bytes(damaged)
    assert _error(tmp_path / "zeroed.mp4") == (f"{tmp_path / 'zeroed.mp4'}: opens but no frame decodes (codec 'FMP4': "
                                               "one OpenCV's FFmpeg cannot decode, or the data is corrupt)")
    assert capfd.readouterr().err == ""


def test_ffmpegs_log_lines_are_told_apart_from_other_lines_coloured_or_not():
    """FFmpeg colours its lines when its first went to a terminal: ESC[...m before the bracket."""
    from signpose.pipeline.image import _DECODER_CHATTER

    text = (b"\x1b[0;33m[mov,mp4,m4a,3gp,3g2,mj2 @ 0x55d0c1a2b3c0] \x1b[0m\x1b[1;31mmoov atom not found\n\x1b[0m"
            b"[mpeg4 @ 0x56214f342fc0] header damaged\nframe 3 of 9 [tracked]\n[2 @ 1] not FFmpeg's\n")
    assert _DECODER_CHATTER.sub(b"", text) == b"frame 3 of 9 [tracked]\n[2 @ 1] not FFmpeg's\n"


def test_a_codec_opencv_cannot_decode_is_named(tmp_path):
    writer = cv2.VideoWriter(str(tmp_path / "clip.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    writer.write(np.zeros((48, 64, 3), np.uint8))
    writer.release()
    data = (tmp_path / "clip.avi").read_bytes()
    assert data.count(b"MJPG") == 2  # the stream header's and the format's codec, which FFmpeg reads
    (tmp_path / "odd.avi").write_bytes(data.replace(b"MJPG", b"ZZZZ"))
    assert _error(tmp_path / "odd.avi") == (f"{tmp_path / 'odd.avi'}: OpenCV's FFmpeg cannot open this AVI file: "
                                            "truncated, corrupt, or in a codec it cannot decode (re-encode it as H.264)")


def test_live_cameras_and_streams_that_cannot_be_opened_say_so():
    assert _error("camera:97") == "camera:97: cannot open camera 97 (no such camera, or it is in use)"
    assert "a live camera is camera:N" in _error("camera:front")
    assert _error("rtsp://127.0.0.1:9/none") == ("rtsp://127.0.0.1:9/none: cannot open the stream (unreachable, "
                                                 "refused, or not a video stream)")


# --- ROS bags --------------------------------------------------------------------------------------------------

def test_an_mcap_bag_gives_its_images_stamps_and_camera(tmp_path):
    stamps = _stamps(3)
    messages = [("/cam/camera_info", _info_msg(ROS2))]
    messages += [("/cam/image_raw", _image_msg(ROS2, i, "rgb8", s)) for i, s in enumerate(stamps)]
    frames, source = _collect(write_mcap(tmp_path / "flight.mcap", messages))
    _assert_frames(frames, 3, stamps)
    assert source.count == 3 and source.fps is None and source.warnings == []
    np.testing.assert_allclose(source.camera.K, np.reshape(K, (3, 3)))
    np.testing.assert_allclose(source.camera.dist, D)
    assert (source.camera.width, source.camera.height) == (W, H)


def test_compressed_images_in_an_mcap_bag_and_the_camera_of_a_parent_namespace(tmp_path):
    stamps = _stamps(2)
    messages = [("/cam/image_raw/compressed", _compressed_msg(ROS2, i, s)) for i, s in enumerate(stamps)]
    messages.append(("/cam/camera_info", _info_msg(ROS2)))
    frames, source = _collect(write_mcap(tmp_path / "flight.mcap", messages))
    _assert_frames(frames, 2, stamps)
    np.testing.assert_allclose(source.camera.K, np.reshape(K, (3, 3)))


@pytest.mark.parametrize("encoding", ["bgr8", "rgb8", "bgra8", "rgba8", "mono8", "mono16"])
def test_image_encodings_in_a_rosbag2_folder(tmp_path, encoding):
    stamps = _stamps(2)
    bag = write_bag2(tmp_path / "bag", [("/camera/image", _image_msg(ROS2, i, encoding, s))
                                         for i, s in enumerate(stamps)])
    assert (bag / "metadata.yaml").exists() and list(bag.glob("*.db3"))
    frames, source = _collect(bag)
    assert source.camera is None and [f.stamp_ns for f in frames] == stamps
    for i, frame in enumerate(frames):
        if encoding.startswith("mono"):
            assert frame.image.shape == (H, W) and frame.image.dtype == np.uint8
            # mono16: 100 (7 bits) as it is, then 2660 (12 bits) shifted down by 4
            assert int(frame.image[0, 0]) == (10 * i if encoding == "mono8" else [100, 2660 >> 4][i])
        else:
            np.testing.assert_array_equal(frame.image, _frame(i))


def test_a_rosbag2_folder_of_mcap_storage_with_its_camera(tmp_path):
    stamps = _stamps(2)
    messages = [("/drone/cam/image_raw/compressed", _compressed_msg(ROS2, i, s)) for i, s in enumerate(stamps)]
    messages.append(("/drone/cam/camera_info", _info_msg(ROS2)))
    bag = write_bag2(tmp_path / "bag", messages, storage=StoragePlugin.MCAP)
    assert list(bag.glob("*.mcap"))
    frames, source = _collect(bag)
    _assert_frames(frames, 2, stamps)
    assert source.name == str(bag) and source.count == 2
    np.testing.assert_allclose(source.camera.K, np.reshape(K, (3, 3)))


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
def test_bayer_images_are_demosaiced_with_ros_pattern_names(tmp_path, pattern):
    """ROS names a Bayer pattern by its top-left 2x2 block, row by row: rggb has red at (0, 0), blue at (1, 1)."""
    colour = _frame(5)
    channel = {"b": 0, "g": 1, "r": 2}
    mosaic = np.zeros((H, W), np.uint8)
    for k, letter in enumerate(pattern):
        mosaic[k // 2::2, k % 2::2] = colour[k // 2::2, k % 2::2, channel[letter]]
    msg = _image_msg(ROS2, 0, "mono8", T0)
    msg.encoding, msg.data = f"bayer_{pattern}8", mosaic.ravel()
    (frame,), _ = _collect(write_mcap(tmp_path / "bayer.mcap", [("/image", msg)]))
    np.testing.assert_array_equal(frame.image[2:-2, 2:-2], colour[2:-2, 2:-2])


def test_header_stamps_left_at_zero_fall_back_to_the_recording_times(tmp_path):
    logged = [T0 + 5, T0 + 100_000_005]
    bag = write_bag2(tmp_path / "bag", [("/image", _image_msg(ROS2, i, "bgr8", 0)) for i in range(2)], log_ns=logged)
    frames, _ = _collect(bag)
    assert [f.stamp_ns for f in frames] == logged and [f.time_s for f in frames] == [0.0, 0.1]


def test_a_ros1_bag_gives_its_compressed_images_and_camera(tmp_path):
    stamps = _stamps(3)
    messages = [("/usb_cam/camera_info", _info_msg(ROS1, ros1=True))]
    messages += [("/usb_cam/image_raw/compressed", _compressed_msg(ROS1, i, s, ros1=True)) for i, s in enumerate(stamps)]
    frames, source = _collect(write_bag1(tmp_path / "flight.bag", messages))
    _assert_frames(frames, 3, stamps)
    np.testing.assert_allclose(source.camera.K, np.reshape(K, (3, 3)))
    np.testing.assert_allclose(source.camera.dist, D)


def test_ros1_raw_images(tmp_path):
    stamps = _stamps(2)
    bag = write_bag1(tmp_path / "raw.bag", [("/image", _image_msg(ROS1, i, "rgb8", s, ros1=True))
                                             for i, s in enumerate(stamps)])
    frames, source = _collect(bag)
    _assert_frames(frames, 2, stamps)
    assert source.camera is None


def test_topics_are_chosen_or_refused_by_name(tmp_path):
    stamps = _stamps(2)
    messages = [("/left/image_raw", _image_msg(ROS2, i, "bgr8", s)) for i, s in enumerate(stamps)]
    messages += [("/right/image_raw/compressed", _compressed_msg(ROS2, i, s)) for i, s in enumerate(stamps)]
    messages.append(("/left/camera_info", _info_msg(ROS2)))
    bag = write_mcap(tmp_path / "stereo.mcap", messages)
    assert _error(bag) == (f"{bag}: the bag has several image topics (/left/image_raw, /right/image_raw/compressed): "
                           "choose one with --topic")
    frames, source = _collect(bag, topic="/right/image_raw/compressed")
    assert len(frames) == 2 and source.camera is None  # /left's camera is not the right one's
    frames, source = _collect(bag, topic="/left/image_raw")
    assert len(frames) == 2 and source.camera is not None
    assert _error(bag, topic="/front/image") == (f"{bag}: no topic /front/image in the bag; its image topics: "
                                                 "/left/image_raw, /right/image_raw/compressed")
    assert "topic /left/camera_info carries sensor_msgs/msg/CameraInfo, not images" in _error(
        bag, topic="/left/camera_info")


def test_a_bag_without_image_topics_lists_its_topics(tmp_path):
    bag = write_mcap(tmp_path / "info.mcap", [("/cam/camera_info", _info_msg(ROS2))])
    assert _error(bag) == (f"{bag}: the bag has no image topics (sensor_msgs/Image or CompressedImage); its topics: "
                           "/cam/camera_info (sensor_msgs/msg/CameraInfo)")


def test_an_uncalibrated_camera_info_is_left_out_with_a_warning(tmp_path):
    messages = [("/cam/camera_info", _info_msg(ROS2, k=[0.0] * 9)),
                ("/cam/image_raw", _image_msg(ROS2, 0, "bgr8", T0))]
    frames, source = _collect(write_mcap(tmp_path / "flight.mcap", messages))
    assert len(frames) == 1 and source.camera is None
    assert len(source.warnings) == 1 and "the CameraInfo on /cam/camera_info is not used" in source.warnings[0]


def test_a_camera_info_without_coefficients_is_read_without_distortion_and_said(tmp_path):
    """What drivers publish for a lens nobody calibrated: its K, not an assumed field of view."""
    info = _info_msg(ROS2)
    info.d = np.zeros(0)
    frames, source = _collect(write_mcap(tmp_path / "flight.mcap", [("/cam/camera_info", info),
                                                                     ("/cam/image_raw", _image_msg(ROS2, 0, "bgr8", T0))]))
    assert source.camera is not None and np.allclose(source.camera.K.ravel(), K) and not source.camera.has_distortion
    assert len(source.warnings) == 1 and "gives no distortion coefficients" in source.warnings[0]


def test_a_topic_or_a_frame_rate_a_source_has_no_use_for_is_said(tmp_path):
    video = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 20, (W, H))
    for i in range(3):
        writer.write(_frame(i))
    writer.release()
    bag = write_mcap(tmp_path / "b.mcap", [("/image", _image_msg(ROS2, 0, "bgr8", T0))])

    def unused(spec, **given) -> str | None:
        with open_source(spec, **given) as source:
            return unused_options(source, topic=given.get("topic"), fps=given.get("fps"))

    assert unused(video, topic="/cam/image_raw") == f"{video} is not a ROS bag, so it has no topic /cam/image_raw"
    assert unused(video, fps=5) == (f"{video} is timed by its own frame rate; a frame rate is given to a folder or "
                                    "list of images")
    assert unused(bag, fps=5).startswith(f"{bag} is timed by its stamps")
    assert unused(bag, topic="/image") is None


def test_damaged_bags_and_frames_are_refused(tmp_path):
    (tmp_path / "junk.mcap").write_bytes(b"not a bag" * 10)
    assert _error(tmp_path / "junk.mcap").startswith(f"{tmp_path / 'junk.mcap'}: cannot be read as a ROS bag: ")
    whole = write_mcap(tmp_path / "whole.mcap", [("/image", _image_msg(ROS2, 0, "bgr8", T0))]).read_bytes()
    (tmp_path / "stopped.mcap").write_bytes(whole[:len(whole) // 2])  # a recording that stopped without its summary
    assert _error(tmp_path / "stopped.mcap").startswith(f"{tmp_path / 'stopped.mcap'}: cannot be read as a ROS bag: ")
    assert _error(tmp_path / "stopped.mcap").endswith("if the recording was cut short, `mcap recover` writes a "
                                                      "readable copy")
    (tmp_path / "junk.bag").write_bytes(b"not a bag" * 10)
    assert "junk.bag: cannot be read as a ROS bag" in _error(tmp_path / "junk.bag")
    bad = _compressed_msg(ROS2, 0, T0)
    bad.data = bad.data[:20]
    bag = write_mcap(tmp_path / "cut.mcap", [("/image/compressed", bad)])
    assert _error(bag).startswith(f"{bag}: message 0 on /image/compressed")
    odd = _image_msg(ROS2, 0, "bgr8", T0)
    odd.encoding = "yuv422"
    bag = write_mcap(tmp_path / "yuv.mcap", [("/image", odd)])
    assert "message 0 on /image has encoding 'yuv422'; readable: mono8" in _error(bag)
    short = _image_msg(ROS2, 0, "bgr8", T0)
    short.data = short.data[:100]
    bag = write_mcap(tmp_path / "short.mcap", [("/image", short)])
    assert "holds 100 bytes, too few for 32x24 px bgr8" in _error(bag)
    big = write_mcap(tmp_path / "big.mcap", [("/image", _image_msg(ROS2, 0, "bgr8", T0))])
    assert "message 0 on /image is 32x24 px" in _error(big, max_pixels=100)


@pytest.mark.skipif(not BOX.exists(), reason="shared data (box.mp4) not found: set SIGNPOSE_SHARED")
def test_a_range_of_frames_is_the_frames_a_read_from_the_start_gives(tmp_path):
    """`frames_from`, where a flight's range starts on a worker: a real H.264 video seeks (from a keyframe, not
    from the start), image files skip the files before, a bag decodes no image before; the same images,
    indices and times (counted from the first frame's) either way."""
    (tmp_path / "frames").mkdir()
    for i in range(5):
        cv2.imwrite(str(tmp_path / "frames" / f"frame{i}.png"), _frame(i))
    bag = write_mcap(tmp_path / "flight.mcap", [("/cam/image_raw", _image_msg(ROS2, i, "rgb8", stamp))
                                                for i, stamp in enumerate(_stamps(5))])
    for spec, start in ((str(BOX), 150), (tmp_path / "frames", 3), (bag, 2)):
        with open_source(spec) as source:
            whole = [frame for frame, _ in zip(source, range(start + 3))]
        with open_source(spec) as source:
            ranged = [frame for frame, _ in zip(source.frames_from(start), range(3))]
        assert [(f.index, f.time_s) for f in ranged] == [(f.index, f.time_s) for f in whole[start:start + 3]]
        assert all(np.array_equal(a.image, b.image) for a, b in zip(ranged, whole[start:]))
