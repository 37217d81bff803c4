"""Chessboard calibration: rendered and projected views of a board under known intrinsics."""

import json
import threading

import cv2
import numpy as np
import pytest
from PIL import Image

import signpose.pipeline.calibrate as calib
from signpose.app.cli import main
from tests.support.chessboards import (BOARD, DIST_TRUE, K_TRUE, SIZE, SQUARE_M, board_poses, projected_corners,
                                       render_boards)
from signpose.pipeline.calibrate import (BoardView, CalibrationError, calibrate, chessboard_image, drop_outliers,
                                find_board, format_report, other_sizes, parse_board, reference_size,
                                too_few_boards_advice)
from signpose.pipeline.camera import Camera, load_camera, save_camera
from signpose.pipeline.evaluate import CORES
from signpose.pipeline.library import LibrarySign
from signpose.pipeline.pose import estimate_pose, rotation_error_deg


def projected_views(n: int, noise_px: float = 0.1, seed: int = 0) -> list[BoardView]:
    rng = np.random.default_rng(seed)
    return [BoardView(f"view{i}.png", SIZE, projected_corners(r, t) + rng.normal(0, noise_px, (BOARD[0] * BOARD[1], 2)))
            for i, (r, t) in enumerate(board_poses(n, seed))]


@pytest.fixture(scope="module")
def rendered():
    """12 rendered board photos (H, W) uint8, their true poses and the boards found in them."""
    images, poses = render_boards(12)
    return images, poses, [find_board(im, BOARD, f"{i}.png") for i, im in enumerate(images)]


def match_order(found: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """`found` corners relabelled to `truth`'s order: the detector may start from the opposite corner."""
    return min((found, found[::-1]), key=lambda f: np.abs(f - truth).max())


def test_find_board_sub_pixel(rendered):
    _, poses, views = rendered
    mean_errors = []
    for view, (r, t) in zip(views, poses):
        assert view.found and view.image_size == SIZE
        truth = projected_corners(r, t)
        err = np.linalg.norm(match_order(view.corners, truth) - truth, axis=1)
        assert err.mean() < 0.2 and err.max() < 0.5
        mean_errors.append(err.mean())
    assert np.mean(mean_errors) < 0.08


def test_find_board_large_image_refined_at_full_resolution(rendered, monkeypatch):
    images, poses, _ = rendered
    monkeypatch.setattr(calib, "MAX_DETECT_SIDE", 320)  # search at half size, as a 12 MP photo would be
    view = find_board(images[0], BOARD)
    truth = projected_corners(*poses[0])
    assert view.found and np.abs(match_order(view.corners, truth) - truth).max() < 0.5


def test_find_board_absent():
    blank = np.full(SIZE[::-1], 200, np.uint8)
    assert not find_board(blank, BOARD).found
    assert not find_board(np.zeros((480, 640), np.uint8), BOARD).found


def test_calibrate_recovers_intrinsics_from_rendered_photos(rendered):
    cal = calibrate(rendered[2], BOARD, SQUARE_M)
    K = cal.camera.K
    assert abs(K[0, 0] / K_TRUE[0, 0] - 1) < 0.005 and abs(K[1, 1] / K_TRUE[1, 1] - 1) < 0.005
    assert abs(K[0, 2] - K_TRUE[0, 2]) < 2 and abs(K[1, 2] - K_TRUE[1, 2]) < 2
    assert abs(cal.camera.dist[0] - DIST_TRUE[0]) < 0.02
    assert cal.rms_px < 0.2 and cal.outliers == () and cal.not_found == ()
    assert cal.camera.source == "calibrated" and (cal.camera.width, cal.camera.height) == SIZE


def test_calibration_yaml_round_trips(tmp_path):
    cal = calibrate(projected_views(10), BOARD, SQUARE_M)
    save_camera(cal.camera, tmp_path / "camera.yaml")
    back = load_camera(tmp_path / "camera.yaml")
    assert np.allclose(back.K, cal.camera.K) and np.allclose(back.dist, cal.camera.dist)
    assert (back.width, back.height) == SIZE


def test_per_view_errors_and_poses():
    views = projected_views(8, noise_px=0.1)
    cal = calibrate(views, BOARD, SQUARE_M)
    # Per-view errors are RMS distances: with 0.1 px noise per axis they sit near 0.1·√2.
    assert np.all((cal.errors_px > 0.08) & (cal.errors_px < 0.2))
    assert np.sqrt(np.mean(cal.errors_px**2)) == pytest.approx(cal.rms_px, rel=1e-6)
    for i, (_, t) in enumerate(board_poses(8)):
        assert np.linalg.norm(cal.tvecs[i] - t) < 0.002
    assert np.all(cal.intrinsics_std > 0) and np.all(cal.intrinsics_std < 2)


def test_outlier_reported_and_dropping_it_improves_rms():
    views = projected_views(12, noise_px=0.1)
    rng = np.random.default_rng(7)
    bad = BoardView("shaky.png", SIZE, views[5].corners + rng.normal(0, 3.0, views[5].corners.shape))
    views[5] = bad
    cal = calibrate(views, BOARD, SQUARE_M)
    assert cal.outliers == (5,)
    assert any(line.startswith("outliers") and "shaky.png" in line for line in format_report(cal).splitlines())
    better = drop_outliers(cal)
    assert better.excluded == (5,) and 5 not in better.used and better.outliers == ()
    assert better.rms_px < cal.rms_px / 3
    assert better.errors_px[5] > 2  # still scored, by its own pose under the new intrinsics
    assert abs(better.camera.K[0, 0] / K_TRUE[0, 0] - 1) < 0.002
    assert drop_outliers(better) is better


def test_outliers_left_after_dropping_are_not_sent_to_drop_outliers_again():
    """After `--drop-outliers` the refit flagged another photo, and the report still said "retake or
    drop them (signpose calibrate --drop-outliers)": the option just used, which drops once."""
    views = projected_views(12, noise_px=0.1)
    rng = np.random.default_rng(7)
    for i, name in ((5, "shaky.png"), (8, "blurry.png")):
        views[i] = BoardView(name, SIZE, views[i].corners + rng.normal(0, 3.0, views[i].corners.shape))
    dropped = calibrate(views, BOARD, SQUARE_M, exclude=(5,))  # as after a round that flagged shaky.png only
    assert dropped.outliers == (8,)
    line = next(line for line in format_report(dropped).splitlines() if line.startswith("outliers"))
    assert "blurry.png" in line and "--drop-outliers" not in line
    assert "stood out only in the refit without the outliers dropped, and is kept" in line
    assert "retake it, or leave it out of the photos" in line
    first = next(line for line in format_report(calibrate(views, BOARD, SQUARE_M)).splitlines()
                 if line.startswith("outliers"))
    assert first.endswith("retake or drop them (signpose calibrate --drop-outliers)")


def test_to_json_reports_every_view_and_the_outlier_threshold():
    views = projected_views(8)
    views[2] = BoardView("shaky.png", SIZE, views[2].corners + np.random.default_rng(3).normal(0, 3.0, (54, 2)))
    views.insert(4, BoardView("blurry.png", SIZE, None))
    cal = calibrate(views, BOARD, SQUARE_M)
    out = cal.to_json()
    assert out["rms_px"] == cal.rms_px and out["used"] == 8 and out["board"] == [9, 6] and out["square_m"] == SQUARE_M
    assert out["camera"]["fx"] == cal.camera.K[0, 0] and set(out["intrinsics_std"]) == {"fx", "fy", "cx", "cy"}
    assert [v["name"] for v in out["views"]] == [v.name for v in views]
    shaky, blurry = out["views"][2], out["views"][4]
    assert shaky["outlier"] and shaky["error_px"] > out["outlier_threshold_px"] == cal.outlier_threshold_px
    assert blurry == {"name": "blurry.png", "found": False, "error_px": None, "tilt_deg": None, "outlier": False,
                      "excluded": False}
    assert sum(v["outlier"] for v in out["views"]) == 1 and 0 < out["views"][0]["tilt_deg"] < 45
    dropped = drop_outliers(cal).to_json()["views"][2]
    assert dropped["excluded"] and not dropped["outlier"] and dropped["error_px"] > 2
    json.dumps(out, allow_nan=False)  # plain JSON: no NaN, no numpy arrays


def test_warnings_for_a_weak_calibration():
    assert calibrate(projected_views(12), BOARD, SQUARE_M).warnings == []
    rng = np.random.default_rng(0)
    face_on = [BoardView(f"{z}.png", SIZE, projected_corners(np.zeros(3), np.array([-0.12, -0.075, z]))
                         + rng.normal(0, 0.1, (54, 2))) for z in (0.4, 0.5, 0.6)]
    assert any("tilted 30-45°" in w for w in calibrate(face_on, BOARD, SQUARE_M).warnings)
    same = projected_views(1) * 3
    assert any("focal length is uncertain" in w for w in calibrate(same, BOARD, SQUARE_M).warnings)
    noisy = projected_views(8, noise_px=2.0)
    cal = calibrate(noisy, BOARD, SQUARE_M)
    assert any(w.startswith("RMS") for w in cal.warnings) and "warning: RMS" in format_report(cal)


def test_not_found_views_are_listed_and_skipped():
    views = projected_views(5)
    views.insert(2, BoardView("blurry.png", SIZE, None))
    cal = calibrate(views, BOARD, SQUARE_M)
    assert cal.not_found == (2,) and np.isnan(cal.errors_px[2]) and np.isnan(cal.tvecs[2]).all()
    assert cal.used == (0, 1, 3, 4, 5)
    assert "blurry.png" in format_report(cal) and "not found" in format_report(cal)


@pytest.mark.parametrize("text, board", [("9x6", (9, 6)), ("9X6", (9, 6)), ("7 x 5", (7, 5)), ("9×6", (9, 6))])
def test_parse_board(text, board):
    assert parse_board(text) == board


@pytest.mark.parametrize("text", ["9", "9x", "x6", "9x6x2", "9,6", "a x b", "-9x6", "2x6", "9x0", "", "101x6"])
def test_parse_board_rejects(text):
    with pytest.raises(CalibrationError, match="inner corners"):
        parse_board(text)


@pytest.mark.parametrize("found, photos, size_is_suspect", [
    (0, 17, True), (2, 17, True), (0, 1, True), (1, 3, True),  # missing from most photos: a size counted in squares?
    (2, 3, False), (1, 2, False), (2, 2, False)])  # found in most: its size is right, photos are missing
def test_too_few_boards_say_to_check_the_board_size_only_when_it_is_missing_from_most_photos(
        found, photos, size_is_suspect):
    """The page said "the 8×6 board found in 0 (at least 3 needed; 15–20 recommended)" and no more,
    when the size had been counted in squares; then, once photos had been removed from a set whose
    board size was right, "found in 2 (at least 3 needed): check the board size" of 2 in 3."""
    advice = too_few_boards_advice((8, 6), found, photos)
    assert advice == ("check the board size: it counts inner corners (where four squares meet) across x down, not "
                      "squares, so 8x6 is a board of 9x7 squares; and the whole board, with its white border, must "
                      "be in view" if size_is_suspect else "add photos of the board")


def test_calibrate_errors():
    views = projected_views(4)
    with pytest.raises(CalibrationError, match="not found in any of the 2"):
        calibrate([BoardView("a", SIZE, None), BoardView("b", SIZE, None)], BOARD, SQUARE_M)
    with pytest.raises(CalibrationError, match=r"^no photo to calibrate from$"):  # the CLI's when none could be read
        calibrate([], BOARD, SQUARE_M)
    with pytest.raises(CalibrationError, match="found in 2 usable image.*at least 3.*; check the board size"):
        calibrate(views[:2] + [BoardView(c, SIZE, None) for c in "cde"], BOARD, SQUARE_M)
    with pytest.raises(CalibrationError, match=r"found in 2 usable image.*at least 3.*\); add photos of the board$"):
        calibrate(views[:2] + [BoardView("c", SIZE, None)], BOARD, SQUARE_M)
    with pytest.raises(CalibrationError, match=r"at least 3.*; add photos of the board$"):  # found in 4, 2 left out
        calibrate(views, BOARD, SQUARE_M, exclude=(0, 1))
    with pytest.raises(CalibrationError, match="portrait.png"):
        calibrate(views + [BoardView("portrait.png", SIZE[::-1], views[0].corners)], BOARD, SQUARE_M)
    with pytest.raises(CalibrationError, match="54 corners.*other.png"):
        calibrate(views + [BoardView("other.png", SIZE, views[0].corners[:40])], BOARD, SQUARE_M)
    for square in (0.0, -0.03, float("nan"), float("inf")):
        with pytest.raises(CalibrationError, match="square size"):
            calibrate(views, BOARD, square)


def test_photos_of_another_size_are_named_with_how_it_differs_and_what_to_do():
    """A photo at half the size was refused with "(portrait and landscape photos need separate
    calibrations)", though it was neither; and the first photo's size was taken as the one, so an odd
    first photo made every other one the odd one out."""
    views = projected_views(4)
    (w, h), corners = SIZE, views[0].corners

    def refusal(*odd: BoardView) -> str:
        with pytest.raises(CalibrationError) as err:
            calibrate([*odd, *views], BOARD, SQUARE_M)
        return str(err.value)

    half = refusal(BoardView("half.png", (w // 2, h // 2), corners / 2))
    assert half == ("the photos must all be one size, as a calibration holds for one: 4 of the 5 with the board are "
                    "640x480 px, but half.png is 320x240 px, the same frame at another resolution (resized, or "
                    "another resolution setting): retake it at 640x480 or leave it out (the calibrated camera is "
                    "scaled to photos of that shape when it is used)")
    turned = refusal(BoardView("tall.png", (h, w), corners))
    assert "tall.png is 480x640 px, the frame turned on its side (portrait and landscape" in turned
    cropped = refusal(BoardView("a.png", (480, 480), corners), BoardView("b.png", (480, 480), corners))
    assert "4 of the 6 with the board are 640x480 px, but a.png, b.png are 480x480 px, another aspect" in cropped
    assert "calibrate that size separately or leave them out" in cropped


def test_photos_of_another_size_are_named_against_the_size_most_share():
    """What a photo's card says before any run: its size and the one most photos share."""
    views = projected_views(3)
    corners = views[0].corners
    half, tall = BoardView("half.png", (320, 240), corners / 2), BoardView("tall.png", (480, 640), corners)
    missed = BoardView("missed.png", (100, 100), None)  # no board: no run is refused over it

    def odd(views: tuple[BoardView, ...], found: list[int]) -> dict[int, str]:
        return other_sizes(views, found, reference_size(views, found))

    assert odd((half, *views, missed), [0, 1, 2, 3]) == {0: "320x240, the others 640x480"}
    assert odd((half, *views, tall), [0, 1, 2, 3, 4]) == {0: "320x240, most 640x480", 4: "480x640, most 640x480"}
    assert odd(tuple(views), [0, 1, 2]) == {}


def test_a_fit_no_camera_could_have_is_a_calibration_error(monkeypatch):
    """OpenCV fits whatever the views allow; intrinsics `Camera` refuses (here fx 20x fy) must
    reach the user as a calibration problem, which the CLI and the page report, not a crash."""
    fit = cv2.calibrateCameraExtended

    def squashed(*args, **kwargs):
        rms, K, *rest = fit(*args, **kwargs)
        K[0, 0] = 20 * K[1, 1]
        return (rms, K, *rest)

    monkeypatch.setattr(calib.cv2, "calibrateCameraExtended", squashed)
    with pytest.raises(CalibrationError, match="no usable camera.*fx/fy"):
        calibrate(projected_views(6), BOARD, SQUARE_M)


def test_chessboard_image_has_the_requested_inner_corners():
    image = chessboard_image((7, 5), square_px=30)
    assert image.shape == (30 * 6 + 60, 30 * 8 + 60)
    assert find_board(image, (7, 5)).found


def write_photos(folder, images) -> list[str]:
    paths = []
    for i, image in enumerate(images):
        paths.append(str(folder / f"board{i:02d}.png"))
        cv2.imwrite(paths[-1], image)
    return paths


def test_cli_calibrate_writes_a_camera_file_recognize_can_read(rendered, tmp_path, capsys):
    paths = write_photos(tmp_path, rendered[0][:5] + [np.full(SIZE[::-1], 255, np.uint8)])
    out = tmp_path / "cam.yaml"
    assert main(["calibrate", *paths, "--board", "9x6", "--square", "0.03", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "overall RMS" in text and "board05.png" in text and "not found" in text and f"wrote {out}" in text
    cam = load_camera(out)
    assert abs(cam.K[0, 0] / K_TRUE[0, 0] - 1) < 0.01 and cam.has_distortion


def test_cli_calibrate_o_dash_writes_the_camera_file_on_stdout(rendered, tmp_path, capsys, monkeypatch):
    """`-o -` wrote a file named "-" and said to use it with `--camera -`."""
    monkeypatch.chdir(tmp_path)
    paths = write_photos(tmp_path, rendered[0][:5])
    assert main(["calibrate", *paths, "--board", "9x6", "--square", "0.03", "-o", "-"]) == 0
    out, err = capsys.readouterr()
    (tmp_path / "piped.yaml").write_text(out)  # as `signpose calibrate ... -o - > piped.yaml` leaves it
    assert abs(load_camera(tmp_path / "piped.yaml").K[0, 0] / K_TRUE[0, 0] - 1) < 0.01
    assert "overall RMS" in err and "wrote" not in err and not (tmp_path / "-").exists()


def test_cli_calibrate_reads_the_renders_saved_as_jpeg(rendered, tmp_path, capsys):
    """Their grey 128 beyond the board, a corner of which was taken for libjpeg's fill of missing data: every
    photo was refused as a damaged JPEG and no camera came out."""
    paths = []
    for i, image in enumerate(rendered[0][:6]):
        paths.append(str(tmp_path / f"board{i:02d}.jpg"))
        cv2.imwrite(paths[-1], image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    out = tmp_path / "cam.yaml"
    assert main(["calibrate", *paths, "--board", "9x6", "--square", "0.03", "-o", str(out)]) == 0
    assert "damaged" not in capsys.readouterr().out
    assert abs(load_camera(out).K[0, 0] / K_TRUE[0, 0] - 1) < 0.01


def test_cli_calibrate_reads_photos_as_the_camera_stored_them(rendered, tmp_path, capsys):
    """A phone held upright stores its sensor's landscape pixels and an EXIF orientation that turns them: read
    turned, those photos were portrait, another size than the others, and a camera file of them would describe
    no pixels as stored, which is what recognize turns with each photo."""
    paths = []
    for i, image in enumerate(rendered[0]):
        exif = Image.Exif()
        exif[0x0112] = (1, 6, 8)[i % 3]
        paths.append(str(tmp_path / f"board{i:02d}.png"))
        Image.fromarray(image).save(paths[-1], exif=exif.tobytes())
    out = tmp_path / "cam.yaml"
    assert main(["calibrate", *paths, "--board", "9x6", "--square", "0.03", "-o", str(out)]) == 0
    capsys.readouterr()
    cam = load_camera(out)
    assert (cam.width, cam.height) == SIZE and np.abs(cam.K - K_TRUE).max() < 2.0


@pytest.mark.skipif(CORES < 2, reason="one core: no second search to run beside the first")
def test_cli_calibrate_searches_photos_side_by_side(rendered, tmp_path, capsys, monkeypatch):
    """Each search waits for a second one to start, which never came when the photos were
    searched one after another; the report still lists them in the order given."""
    together = threading.Barrier(2, timeout=10)

    def find_board_beside_another(gray, board, name=""):
        together.wait()
        return find_board(gray, board, name)

    monkeypatch.setattr(calib, "find_board", find_board_beside_another)
    paths = write_photos(tmp_path, rendered[0][:4])
    assert main(["calibrate", *paths, "--board", "9x6", "--square", "0.03", "-o", str(tmp_path / "c.yaml")]) == 0
    report = capsys.readouterr().out
    listed = [report.index(f"board{i:02d}.png") for i in range(4)]
    assert listed == sorted(listed)


def test_cli_calibrate_refuses_a_photo_given_twice(rendered, tmp_path, capsys):
    """`board_0*.jpg board_0*.jpg` fitted 20 views of 10 photos and said so, its ± 1σ too small."""
    paths = write_photos(tmp_path, rendered[0][:3])
    out = tmp_path / "c.yaml"
    assert main(["calibrate", *paths, paths[1], "--board", "9x6", "--square", "0.03", "-o", str(out)]) == 2
    assert f"a photo is given more than once: {paths[1]}" in capsys.readouterr().err and not out.exists()


def test_cli_calibrate_drop_outliers(tmp_path, capsys, monkeypatch):
    views = projected_views(10)
    views[3] = BoardView("board03.png", SIZE, views[3].corners + np.random.default_rng(1).normal(0, 3, (54, 2)))
    by_name = {f"board{i:02d}.png": BoardView(f"board{i:02d}.png", SIZE, v.corners) for i, v in enumerate(views)}
    monkeypatch.setattr(calib, "find_board", lambda gray, board, name: by_name[name])
    paths = write_photos(tmp_path, [np.zeros((SIZE[1], SIZE[0]), np.uint8)] * 10)
    out = tmp_path / "cam.yaml"
    assert main(["calibrate", *paths, "--board", "9x6", "--square", "0.03", "-o", str(out), "--drop-outliers"]) == 0
    text = capsys.readouterr().out
    assert "board03.png" in text and "dropped as an outlier" in text
    assert load_camera(out).K[0, 0] == pytest.approx(K_TRUE[0, 0], rel=0.002)


@pytest.mark.parametrize("argv, message", [
    (["--board", "9by6", "--square", "0.03"], "COLSxROWS"),
    (["--board", "9x6", "--square", "0"], "square size"),
])
def test_cli_calibrate_bad_options(tmp_path, capsys, argv, message):
    paths = write_photos(tmp_path, [np.full((100, 100), 255, np.uint8)])
    assert main(["calibrate", *paths, *argv, "-o", str(tmp_path / "c.yaml")]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "c.yaml").exists()


def test_cli_calibrate_board_nowhere(tmp_path, capsys):
    paths = write_photos(tmp_path, [np.full((480, 640), 255, np.uint8)] * 3)
    assert main(["calibrate", *paths, "--board", "9x6", "--square", "0.03", "-o", str(tmp_path / "c.yaml")]) == 2
    err = capsys.readouterr().err
    assert "not found in any of the 3 image(s)" in err and "inner corners" in err


def test_cli_calibrate_unreadable_image_is_reported(rendered, tmp_path, capsys):
    paths = write_photos(tmp_path, rendered[0][:3])
    (tmp_path / "broken.jpg").write_bytes(b"not a jpeg")
    out = tmp_path / "c.yaml"
    assert main(["calibrate", *paths, str(tmp_path / "broken.jpg"), "--board", "9x6", "--square", "0.03",
                 "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "broken.jpg" in err and "1 of 4 image(s) could not be used" in err and out.exists()  # as recognize says


@pytest.mark.parametrize("method", ["ippe_lm", "paper"])
def test_pose_uses_the_lens_distortion(method):
    """Under strong barrel distortion a sign off-centre gives a visibly wrong pose when the distortion
    is ignored, and the true pose when the calibrated distortion is used."""
    K = np.array([[420.0, 0, 320], [0, 420.0, 240], [0, 0, 1]])
    dist = np.array([-0.38, 0.16, 0.0, 0.0, 0.0])
    sign = LibrarySign("plate", "plate", "", "plate.png", 0.6, 0.3, np.zeros((150, 300), np.uint8))
    src = np.stack(np.meshgrid(np.linspace(10, 290, 8), np.linspace(10, 140, 5)), -1).reshape(-1, 2)
    rvec, tvec = np.array([0.15, -0.5, 0.05]), np.array([-0.55, -0.35, 1.6])
    dst, _ = cv2.projectPoints(sign.to_metric(src), rvec, tvec, K, dist)
    dst = dst.reshape(-1, 2) + np.random.default_rng(1).normal(0, 0.1, (len(src), 2))
    H = cv2.findHomography(src, dst)[0]
    R_true = cv2.Rodrigues(rvec)[0]
    true_position = -R_true.T @ tvec

    def errors(camera):
        pose = estimate_pose(H, src, dst, sign, camera, method)
        return (np.linalg.norm(pose.camera_position - true_position), rotation_error_deg(pose.R, R_true),
                pose.reprojection_rmse_px)

    pos_ok, rot_ok, rmse_ok = errors(Camera(K, dist, 640, 480, "calibrated"))
    pos_bad, rot_bad, rmse_bad = errors(Camera(K, np.zeros(5), 640, 480, "calibrated, distortion ignored"))
    assert pos_ok < 0.02 and rot_ok < 0.5 and rmse_ok < 0.2  # 1.8 m away, 0.1 px noise
    assert pos_bad > 0.3 and rot_bad > 10
    assert rmse_bad > 3 * rmse_ok
