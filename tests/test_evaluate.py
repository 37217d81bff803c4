import functools
import json
import math
import multiprocessing
import os
import signal
import time
import shutil
import threading
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

import signpose.pipeline.evaluate as evaluate_module
import signpose.pipeline.recognize as recognize_module
from signpose.app.image_store import check_image_header
from signpose.pipeline.evaluate import (Dataset, DatasetError, ImageResult, Sample, check_labels, evaluate, format_table,
                               load_dataset, summarize, text_columns)
from signpose.pipeline.settings import preset
from tests.support.scene_images import TURNED_SCENE, png_bomb, with_orientation

SCENES = Path(__file__).resolve().parent.parent / "sample_images" / "scenes"

SET3 = SCENES.parent / "datasets" / "set3"



def test_loads_truth_json_with_camera():
    dataset = load_dataset(SET3)
    assert dataset.name == "set3" and len(dataset) == 5
    assert dataset.camera is not None and (dataset.camera.width, dataset.camera.height) == (640, 480)
    positives = [s for s in dataset.samples if s.label is not None]
    assert positives and all(s.R.shape == (3, 3) and s.corners.shape == (4, 2) for s in positives)
    assert all(s.R is None and s.category == "negative" for s in dataset.samples if s.label is None)


def test_loads_label_folders(tmp_path):
    images = sorted(SET3.glob("*.jpg"))
    for folder, image in zip(["security_compound", "none", "Negative"], images):
        (tmp_path / folder).mkdir()
        shutil.copy(image, tmp_path / folder / image.name)
    (tmp_path / "none" / "notes.txt").write_text("not an image")
    dataset = load_dataset(tmp_path)
    assert sorted((s.label or "-", s.path.parent.name) for s in dataset.samples) == [
        ("-", "Negative"), ("-", "none"), ("security_compound", "security_compound")]
    assert dataset.camera is None


@pytest.mark.parametrize("truth, message", [
    ({"images": {}}, "at least one image"),
    ({"images": {"missing.jpg": {"label": None}}}, "not found"),
    ({"images": {"a.jpg": {"label": 3}}}, "label must be"),
    ({"images": {"a.jpg": {"label": "x", "R": [[1, 0], [0, 1]]}}}, "R must be 3x3"),
    # A named camera that was missing was ignored: the poses were measured under an assumed field of view.
    ({"camera": "cam_missing.yaml", "images": {"a.jpg": {"label": None}}}, "'cam_missing.yaml' is not a file in "),
    ({"camera": ".", "images": {"a.jpg": {"label": None}}}, "the \"camera\" file '.' is not a file in "),
    ({"camera": 5, "images": {"a.jpg": {"label": None}}}, "\"camera\" must be a camera file name; got 5"),
])
def test_rejects_bad_truth(tmp_path, truth, message):
    cv2.imwrite(str(tmp_path / "a.jpg"), np.zeros((8, 8, 3), np.uint8))
    (tmp_path / "truth.json").write_text(json.dumps(truth))
    with pytest.raises(DatasetError, match=message):
        load_dataset(tmp_path)


HUGE = "x" * 1_000_000


@pytest.mark.parametrize("images, words", [
    ({HUGE: 5}, "image 'xxxxxxxxxxxx...xxxxxxxxxxxxx': each image needs an object"),
    ({HUGE: {"label": None}}, "image 'xxxxxxxxxxxx...xxxxxxxxxxxxx': file not found in "),  # was OSError, name whole
    ({"a.jpg": {"label": list(range(10_000))}}, "label must be a sign id or null; got [0, 1, 2, 3, 4, 5, ...]"),
])
def test_a_truth_file_error_quotes_a_huge_value_shortened(tmp_path, images, words):
    """truth.json's values were quoted whole, a megabyte file name in every error about its image; a name too long
    for the file system was an OSError naming it."""
    cv2.imwrite(str(tmp_path / "a.jpg"), np.zeros((8, 8, 3), np.uint8))
    (tmp_path / "truth.json").write_text(json.dumps({"images": images}))
    with pytest.raises(DatasetError) as refused:
        load_dataset(tmp_path)
    assert words in str(refused.value) and len(str(refused.value)) < 300


def test_unknown_labels_are_quoted_shortened(tmp_path, library):
    cv2.imwrite(str(tmp_path / "a.jpg"), np.zeros((8, 8, 3), np.uint8))
    (tmp_path / "truth.json").write_text(json.dumps({"images": {"a.jpg": {"label": HUGE}}}))
    with pytest.raises(DatasetError) as refused:
        check_labels([load_dataset(tmp_path)], library)
    assert str(refused.value).startswith("label(s) 'xxxxxxxxxxxx...xxxxxxxxxxxxx' are not in the library (")
    assert len(str(refused.value)) < 300

def test_rejects_empty_folder_and_unknown_labels(tmp_path, library):
    with pytest.raises(DatasetError, match="no truth.json"):
        load_dataset(tmp_path)
    (tmp_path / "exit_sign").mkdir()
    shutil.copy(next(SET3.glob("*.jpg")), tmp_path / "exit_sign" / "a.jpg")
    with pytest.raises(DatasetError, match="exit_sign"):
        evaluate([load_dataset(tmp_path)], library, preset("default"))


def fake_recognize(answers):
    """A stand-in for pipeline.recognize answering from the truth, or the label in `answers[file]`."""
    truth = {s.path.name: s for s in load_dataset(SET3).samples}

    def recognize(image, library, settings, camera, cache=None):
        sample = next(s for name, s in truth.items() if np.array_equal(image, cv2.imread(str(SET3 / name))))
        label = answers.get(sample.path.name, sample.label)
        pose = None if sample.R is None else SimpleNamespace(R=sample.R, t=sample.t * 1.02)
        corners = None if sample.corners is None else sample.corners + [3, 4]
        return SimpleNamespace(label=label, pose=pose, corners=corners, timing_ms={"total": 10.0},
                               by_plaque=False, margin=0)
    return recognize


def test_a_tilt_error_is_a_position_error_however_small_the_translation_error(monkeypatch, library):
    """A pose tilted 10° about the camera's y axis with t exact is 0 % off in translation, yet its
    camera stands 2·sin 5° times t across that axis from where it is: localisation reads the
    position, which evaluate did not report."""
    tilt = cv2.Rodrigues(np.array([0.0, np.radians(10), 0.0]))[0]
    truth = {s.path.name: s for s in load_dataset(SET3).samples}

    def tilted(image, library, settings, camera, cache=None):
        sample = next(s for name, s in truth.items() if np.array_equal(image, cv2.imread(str(SET3 / name))))
        pose = None if sample.R is None else SimpleNamespace(R=tilt @ sample.R, t=sample.t)
        return SimpleNamespace(label=sample.label, pose=pose, corners=sample.corners, timing_ms={"total": 10.0},
                               by_plaque=False, margin=0)

    monkeypatch.setattr(recognize_module, "recognize", tilted)
    report = evaluate([load_dataset(SET3)], library, preset("default"), workers=1)
    posed = [r for r in report.results if r.sample.R is not None]
    assert posed and all(r.translation_error_pct == 0 for r in posed)
    assert [r.position_error_m for r in posed] == pytest.approx(
        [2 * np.linalg.norm(r.sample.t[[0, 2]]) * np.sin(np.radians(5)) for r in posed])
    assert report.to_json()["total"]["position_error_m"]["median"] > 0.1
    assert "position med/p90" in format_table(report)


def test_counts_errors_and_confusion(monkeypatch, library):
    dataset = load_dataset(SET3)
    negative = next(s.path.name for s in dataset.samples if s.label is None)
    positive = next(s for s in dataset.samples if s.label is not None)
    other = next(i for i in library.ids if i != positive.label)
    monkeypatch.setattr(recognize_module, "recognize",
                        fake_recognize({negative: "security_compound", positive.path.name: other}))
    calls = []
    # One worker: the stand-in recognize is patched into this process only.
    report = evaluate([dataset], library, preset("default"), progress=lambda i, n: calls.append((i, n)), workers=1)
    assert calls == [(i, 5) for i in range(1, 6)]
    s = report.datasets["set3"]
    assert (s.images, s.correct, s.negatives, s.false_positives) == (5, 3, 1, 1)
    assert s.mean_time_ms == 10.0
    assert s.rotation_deg == pytest.approx((0.0, 0.0), abs=1e-6)
    assert s.translation_pct[0] == pytest.approx(2.0)
    assert [r.position_error_m for r in report.results if r.correct and r.sample.R is not None] == pytest.approx(
        [0.02 * np.linalg.norm(r.sample.t) for r in report.results if r.correct and r.sample.R is not None])
    assert s.corner_px[0] == pytest.approx(5.0)
    labels = report.labels
    assert labels[-1] == "none" and report.confusion.sum() == 5
    assert report.confusion[labels.index("none"), labels.index("security_compound")] == 1
    assert report.confusion[labels.index(positive.label), labels.index(other)] == 1
    text = format_table(report)
    assert "set3" in text and "wrong answers" in text and negative in text


def test_an_unreadable_image_is_named_once_among_the_wrong_answers(tmp_path, library):
    (tmp_path / "none").mkdir()
    bad = tmp_path / "none" / "bad.jpg"
    bad.write_text("not a jpeg")
    table = format_table(evaluate([load_dataset(tmp_path)], library, preset("default"), workers=1))
    assert f"  {bad}: not an image file (use JPEG" in table and table.count(str(bad)) == 1  # not "bad.jpg: bad.jpg: ..."


def test_table_columns_line_up_after_a_name_with_arabic_vowel_marks(library):
    # Four of مُجَمَّع's eight characters are marks that take no column: padded by len(), its row
    # came out four columns short.
    datasets = [load_dataset(SET3), load_dataset(SET3)]
    datasets[0].name = "مُجَمَّع"
    for dataset in datasets:
        del dataset.samples[1:]   # the rows' widths do not depend on how many images a row counts
    rows = format_table(evaluate(datasets, library, preset("default"), workers=1)).splitlines()[2:5]
    assert [row.split()[0] for row in rows] == ["مُجَمَّع", "set3", "all"]
    assert len({text_columns(row[:row.index("%")]) for row in rows}) == 1


def test_summary_of_nothing_measurable():
    s = summarize([])
    assert s.images == 0 and s.rotation_deg is None and np.isnan(s.accuracy)


def test_runs_the_real_pipeline(library):
    report = evaluate([load_dataset(SET3)], library, preset("default"))
    s = report.datasets["set3"]
    assert s.images == 5 and s.correct >= 4 and s.false_positives == 0
    assert s.rotation_deg is not None and s.rotation_deg[0] < 5
    assert "set3" in format_table(report)


def _measured_here(job, library, settings, check_image):
    """Stands in for `_measure` in this process only (the workers are spawned): slow, and marks its results.
    Slow enough that 40 jobs outlast a worker's start-up (import numpy, OpenCV and the pipeline) on a busy
    machine, where at 0.05 s this process took every job before the worker was up."""
    dataset, sample, _ = job
    time.sleep(0.2)
    return ImageResult(dataset, sample, None, math.nan, error="measured in the calling process")


@pytest.mark.slow
def test_worker_processes_share_the_images_and_keep_their_order(monkeypatch, library):
    datasets = [load_dataset(SET3)] * 8  # 40 images: enough for a worker to be up before they run out
    alone = evaluate(datasets, library, preset("default"), workers=1)
    monkeypatch.setattr(evaluate_module, "_measure", _measured_here)
    threads = cv2.getNumThreads()
    pooled = evaluate(datasets, library, preset("default"), workers=2)
    assert cv2.getNumThreads() == threads  # this process worked on one thread, and is given its own back
    assert [r.sample.path for r in pooled.results] == [r.sample.path for r in alone.results]
    by_worker = [(a, p) for a, p in zip(alone.results, pooled.results) if p.error is None]
    assert 0 < len(by_worker) < len(pooled.results)  # both processes took images
    assert [(p.predicted, p.rotation_error_deg) for _, p in by_worker] == \
        [(a.predicted, a.rotation_error_deg) for a, _ in by_worker]


def test_the_image_check_reaches_the_worker_processes(monkeypatch, library, tmp_path):
    big = tmp_path / "big.png"
    big.write_bytes(png_bomb(3000, 2000))
    dataset = Dataset("big", tmp_path, [Sample(big, None)] * 40)
    monkeypatch.setattr(evaluate_module, "_measure", _measured_here)  # the workers run the real one
    report = evaluate([dataset], library, preset("default"), workers=2,
                      check_image=functools.partial(check_image_header, max_pixels=5_000_000))
    by_worker = [r.error for r in report.results if r.error != "measured in the calling process"]
    assert by_worker and all("6.0 megapixels, more than the limit of 5" in e for e in by_worker)


def test_stopping_early_reads_what_the_workers_still_send(monkeypatch, library):
    """A worker stopping with a result that waited for room in the pipe never stopped, as nobody read
    the pipe any more, and the pool waited for it forever: here every result is larger than a pipe holds."""
    image = sorted(SET3.glob("*.jpg"))[0]
    jobs = [("big", Sample(image, None, params={"padding": "x" * 300_000}), None)] * 40
    monkeypatch.setattr(evaluate_module, "_measure", _measured_here)  # the workers run the real one
    measured = evaluate_module._measure_all(jobs, library, preset("default"), None, workers=2)
    next(r for r in measured if r.error != "measured in the calling process")  # the worker is measuring
    closing = threading.Thread(target=measured.close, daemon=True)  # as a Ctrl-C or a `closing` would
    closing.start()
    closing.join(30)
    assert not closing.is_alive(), "the workers never stopped"


def test_a_worker_error_reaches_the_caller_with_where_it_came_from(monkeypatch, library):
    broken = Sample(path=None, label=None)  # the spawned worker's real _measure raises on it
    dataset = Dataset("broken", SET3, [broken] * 40)
    monkeypatch.setattr(evaluate_module, "_measure", _measured_here)
    with pytest.raises(TypeError) as raised:
        evaluate([dataset], library, preset("default"), workers=2)
    assert isinstance(raised.value.__cause__, evaluate_module.WorkerTraceback)
    assert "in _measure" in str(raised.value.__cause__)


def test_workers_waiting_for_their_work_end_when_the_caller_fails_before_handing_it_out(monkeypatch, library):
    def fail(library, settings):
        raise RuntimeError("no features")

    monkeypatch.setattr(evaluate_module, "library_features", fail)  # the workers are started before it runs
    with pytest.raises(RuntimeError, match="no features"):
        evaluate([load_dataset(SET3)], library, preset("default"), workers=2)
    assert not multiprocessing.active_children()


def _slow_check(data: bytes, name: str) -> None:
    """An image check that keeps a worker on each image long enough to be killed in the middle of one."""
    time.sleep(0.2)


@pytest.mark.slow
def test_a_worker_killed_outright_breaks_the_pool_instead_of_leaving_a_wait(monkeypatch, library):
    dataset = Dataset("many", SET3, [Sample(sorted(SET3.glob("*.jpg"))[0], None)] * 40)
    monkeypatch.setattr(evaluate_module, "_measure", _measured_here)  # the worker runs the real one
    measured = evaluate_module._measure_all([("many", s, None) for s in dataset.samples], library,
                                            preset("default"), _slow_check, workers=2)
    next(r for r in measured if r.error != "measured in the calling process")  # the worker is measuring
    [worker] = multiprocessing.active_children()
    os.kill(worker.pid, signal.SIGKILL)  # as the OOM killer does, in the middle of its next image
    with pytest.raises(BrokenProcessPool):
        list(measured)


def test_a_failure_inside_the_pipeline_is_that_images_error(fail_first_segmentation, library):
    dataset = load_dataset(SET3)
    report = evaluate([dataset], library, preset("default"), workers=1)  # patched in this process only
    errors = [r for r in report.results if r.error is not None]
    assert len(errors) == 1 and "pipeline failed on" in errors[0].error and "simulated defect" in errors[0].error
    assert sum(r.correct for r in report.results) == len(dataset.samples) - 1


def test_without_a_camera_the_assumed_field_of_view_spans_the_sensor_however_the_photo_was_turned(tmp_path, library):
    """A sample scene, taken with a 60° camera, tagged with each EXIF orientation that turns it: shown on its side
    (6, 8), the assumed 60° spanned its height as shown instead of the sensor's width, and put the camera 0.38 m
    off."""
    truth = json.loads((SCENES / "truth.json").read_text())["images"][TURNED_SCENE]
    scene = (SCENES / TURNED_SCENE).read_bytes()
    for orientation in (1, 3, 6, 8):
        (tmp_path / f"{orientation}.jpg").write_bytes(with_orientation(scene, orientation))
    (tmp_path / "truth.json").write_text(json.dumps({"images": {f"{o}.jpg": {
        "label": truth["label"], "R": truth["R"], "t": truth["t"]} for o in (1, 3, 6, 8)}}))
    report = evaluate([load_dataset(tmp_path)], library, preset("default"), workers=1)
    errors = [result.position_error_m for result in report.results]
    assert len(errors) == 4 and max(errors) < 0.005, errors
