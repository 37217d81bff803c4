"""evaluate, track and sweep on a real Dask cluster (a scheduler and two worker processes on loopback), and
the results kept with --results: the same answers as a local run, a worker killed mid-run, resumed runs."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import pytest

from signpose.app.cli import main
from signpose.app.workspace import WorkspaceConfig
from signpose.pipeline.evaluate import load_dataset
from signpose.pipeline.library import NO_SIGN
from signpose.pipeline.results import ResultStore, affecting_settings, result_key
from signpose.pipeline.settings import Settings
from tests.support.serving import TIMEOUT_S, running_workspace, sample_library_copy, upload, wait_idle

distributed = pytest.importorskip("distributed")

pytestmark = pytest.mark.slow

SAMPLES = Path(__file__).resolve().parent.parent / "sample_images"
DATASETS = [str(SAMPLES / "datasets" / name) for name in ("set1", "set2", "set3")]
FLIGHT = str(SAMPLES / "flights" / "corridor" / "flight.mp4")


@pytest.fixture(scope="module")
def cluster():
    """A scheduler and two single-threaded worker processes on loopback: its address."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  host="127.0.0.1") as local:
        yield local.scheduler_address


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def without_times(value):
    """A command's JSON with every timing left out: the only part two runs may differ in."""
    if isinstance(value, dict):
        return {k: without_times(v) for k, v in value.items() if k not in ("time_ms", "timing_ms")}
    if isinstance(value, list):
        return [without_times(v) for v in value]
    return value


def test_evaluate_on_the_cluster_answers_as_a_local_run(cluster, capsys):
    code, local, _ = run(capsys, "evaluate", *DATASETS, "--json", "--workers", "2")
    assert code == 0
    code, remote, err = run(capsys, "evaluate", *DATASETS, "--json", "--dask", cluster, "--chunk", "3")
    assert code == 0 and "26 images computed" in err
    assert without_times(json.loads(remote)) == without_times(json.loads(local))
    # The workers read the files themselves (they share this machine's paths).
    code, by_path, err = run(capsys, "evaluate", *DATASETS, "--json", "--dask", cluster, "--shared-paths")
    assert code == 0 and without_times(json.loads(by_path)) == without_times(json.loads(local))


def test_track_on_the_cluster_answers_as_a_local_run(cluster, capsys):
    code, local, _ = run(capsys, "track", FLIGHT, "--json", "--max-frames", "60")
    assert code == 0
    code, remote, err = run(capsys, "track", FLIGHT, FLIGHT, "--json", "--max-frames", "60", "--dask", cluster)
    assert code == 0 and "2 chunk(s) computed" in err
    local_lines = [without_times(json.loads(line)) for line in local.splitlines()]
    remote_lines = [without_times(json.loads(line)) for line in remote.splitlines()]
    assert len(local_lines) == 60 and remote_lines == local_lines * 2
    assert any(line["signs"] for line in local_lines)


def test_a_worker_killed_mid_run_loses_only_its_chunk(cluster, capsys):
    """One of the two workers is killed (SIGKILL) while it runs a chunk: the scheduler runs that chunk on the
    other, every image is answered as locally, and the summary names the chunk run again."""
    code, local, _ = run(capsys, "evaluate", *DATASETS, "--json", "--workers", "2")
    killed: list[str] = []

    def kill_a_busy_worker() -> None:
        with distributed.Client(cluster, timeout=TIMEOUT_S) as client:
            pids = client.run(os.getpid)
            deadline = time.monotonic() + TIMEOUT_S
            while time.monotonic() < deadline:
                busy = [worker for worker, keys in client.processing().items() if keys]
                if busy:
                    os.kill(pids[busy[0]], signal.SIGKILL)
                    killed.append(busy[0])
                    return
                time.sleep(0.005)

    killer = threading.Thread(target=kill_a_busy_worker)
    killer.start()
    code, remote, err = run(capsys, "evaluate", *DATASETS, "--json", "--dask", cluster, "--chunk", "1")
    killer.join()
    assert killed and code == 0
    assert without_times(json.loads(remote)) == without_times(json.loads(local))
    assert "chunk(s) run again after a lost worker" in err, err
    with distributed.Client(cluster, timeout=TIMEOUT_S) as client:  # the nanny brings a new worker up
        client.wait_for_workers(2, timeout=TIMEOUT_S)


def test_a_resumed_run_computes_only_what_is_missing(cluster, capsys, tmp_path):
    results = tmp_path / "results"
    argv = ["evaluate", DATASETS[0], "--json", "--results", str(results)]
    code, first, err = run(capsys, *argv, "--dask", cluster)
    assert code == 0 and "10 images computed, 0 taken from --results" in err
    stored = sorted(results.glob("*/*.json"))
    assert len(stored) == 10
    for path in stored[:3]:  # a run cut short before these were done
        path.unlink()
    code, again, err = run(capsys, *argv, "--dask", cluster)
    assert code == 0 and "3 images computed, 7 taken from --results" in err
    assert without_times(json.loads(again)) == without_times(json.loads(first))
    # A setting that feeds recognition: every image again; back to the defaults: none (here, without Dask).
    settings = tmp_path / "settings.json"
    settings.write_text(json.dumps({"min_inliers": 12}))
    code, _, err = run(capsys, *argv, "--settings", str(settings), "--dask", cluster)
    assert "10 images computed, 0 taken from --results" in err
    code, back, err = run(capsys, *argv, "--workers", "1")
    assert "0 images computed, 10 taken from --results" in err
    assert without_times(json.loads(back)) == without_times(json.loads(first))


def test_a_flight_in_frame_ranges_resumes_and_reports_what_a_whole_run_does(cluster, capsys, tmp_path):
    """80 frames in two ranges of 40, the second tracked after its warm-up of 30 frames: the same signs on every
    frame as a local run over the whole flight, the same camera positions within a millimetre; the second
    range's track ids follow the first's. A range's result kept with --results is not computed again."""
    code, whole, _ = run(capsys, "track", FLIGHT, "--json", "--max-frames", "80")
    argv = ["track", FLIGHT, "--json", "--max-frames", "80", "--chunk-frames", "40", "--results", str(tmp_path),
            "--dask", cluster]
    code, first, err = run(capsys, *argv)
    assert code == 0 and "2 chunk(s) computed, 0 taken" in err
    lines = [json.loads(line) for line in first.splitlines()]
    assert len(lines) == 80 and [line["frame"] for line in lines] == list(range(80))
    for ours, theirs in zip(lines, map(json.loads, whole.splitlines())):
        assert sorted(s["label"] for s in ours["signs"]) == sorted(s["label"] for s in theirs["signs"]), ours["frame"]
        for sign in ours["signs"]:
            same = next(s for s in theirs["signs"] if s["label"] == sign["label"])
            assert math.dist(sign["pose"]["camera_position"], same["pose"]["camera_position"]) < 1e-3
    ids = [{s["track_id"] for line in lines[start:start + 40] for s in line["signs"]} for start in (0, 40)]
    assert ids[0] and ids[1] and min(ids[1]) > max(ids[0])
    stored = {json.loads(path.read_text())["records"][0]["frame"]: path for path in tmp_path.glob("*/*.json")}
    assert sorted(stored) == [0, 40]
    stored[0].unlink()  # a run cut short before its first range was done
    code, again, err = run(capsys, *argv)
    assert code == 0 and "1 chunk(s) computed, 1 taken" in err
    assert [without_times(json.loads(line)) for line in again.splitlines()] == list(map(without_times, lines))


def test_a_sweep_over_a_flight_on_the_cluster_answers_as_a_local_run(cluster, capsys):
    """The flight scored against its ground truth at each value (recall, wrong labels, position error), in
    ranges of 20 frames: the same figures from this machine's processes and from the cluster."""
    argv = ["sweep", "threshold", "--lo", "0.3", "--hi", "0.95", "--steps", "2", str(Path(FLIGHT).parent),
            "--max-frames", "40", "--chunk-frames", "20", "--json"]
    code, local, _ = run(capsys, *argv, "--workers", "2")
    assert code == 0
    code, remote, err = run(capsys, *argv, "--dask", cluster)
    assert code == 0 and "4 flight chunk(s) computed" in err
    assert json.loads(remote) == json.loads(local)
    flight = json.loads(local)["flights"][0]
    assert flight["frames"] == [40, 40] and flight["wrong_labels"] == [0, 0]
    assert flight["recall_pct"][1] > 90 > flight["recall_pct"][0]  # the values tell the settings apart
    assert all(error < 5 for error in flight["position_error_cm_p50"])


def test_the_sweep_command_tallies_as_the_pages_sweep(cluster, capsys, tmp_path):
    """The page's sweep (GET /api/sweep on a real server holding set1's photos, labelled) and `signpose sweep`
    on the folder, on the cluster: the same tally."""
    folder = Path(DATASETS[0])
    config = WorkspaceConfig(state_dir=tmp_path / "state", library_dir=sample_library_copy(tmp_path),
                             camera_file=folder / "camera.yaml", load_samples=False, workers=2)
    query = {"param": "min_inliers", "lo": 4, "hi": 60, "steps": 3}
    with running_workspace(config) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as client:
        samples = load_dataset(folder).samples
        upload(client, *[(s.path.name, s.path.read_bytes(), s.label or NO_SIGN) for s in samples]).raise_for_status()
        wait_idle(client)
        page = client.get("/api/sweep", params=query).json()
    capsys.readouterr()  # what the server printed
    code, out, _ = run(capsys, "sweep", "min_inliers", "--lo", "4", "--hi", "60", "--steps", "3", str(folder),
                       "--json", "--dask", cluster)
    assert code == 0
    assert json.loads(out) == page
    assert len(set(page["correct"])) > 1  # the values tell the images apart


def test_without_dask_no_dask_module_is_imported(tmp_path):
    code = ("import sys\nfrom signpose.app.cli import main\n"
            f"assert main(['evaluate', {DATASETS[2]!r}, '--workers', '1', '--results', {str(tmp_path)!r}]) == 0\n"
            "loaded = sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed'))\n"
            "assert not loaded, loaded")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


@pytest.mark.parametrize("setup, address, words", [
    ("sys.modules['distributed'] = None", "tcp://127.0.0.1:8786", "pip install 'signpose[dask]'"),
    ("", "tcp://127.0.0.1:1", "cannot reach the Dask scheduler at tcp://127.0.0.1:1"),
])
def test_a_cluster_that_cannot_be_used_is_one_clear_line(setup, address, words):
    code = (f"import sys\n{setup}\nfrom signpose.app.cli import main\n"
            f"sys.exit(main(['evaluate', {DATASETS[2]!r}, '--dask', {address!r}]))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and words in done.stderr and done.stderr.count("\n") == 1, done.stderr


def test_a_result_key_holds_the_settings_that_feed_its_stages_only(tmp_path):
    pose_only = affecting_settings(Settings(), ["pose"])
    assert set(pose_only) == {"pose_method", "ambiguity_ratio"}  # as Settings' metadata declares
    context = {"kind": "test"}
    key = result_key(Settings(), ["pose"], context)
    assert result_key(Settings(threshold=0.6), ["pose"], context) == key
    assert result_key(Settings(ambiguity_ratio=0.7), ["pose"], context) != key
    store = ResultStore(tmp_path)
    assert store.get("content", key) is None
    store.put("content", key, {"answer": 1})
    assert store.get("content", key) == {"answer": 1}
    assert [p.name for p in (tmp_path / "content").iterdir()] == [f"{key}.json"]  # no temporary file left
    store.path("content", key).write_text("{cut sho")  # a file cut short is computed again
    assert store.get("content", key) is None


def test_sweep_and_track_refuse_what_they_cannot_do_in_one_line(capsys, tmp_path):
    code, out, err = run(capsys, "sweep", "detector", "--lo", "0", "--hi", "1", DATASETS[2])
    assert code == 2 and out == "" and "cannot sweep 'detector'; choose a numeric setting" in err
    code, _, err = run(capsys, "track", FLIGHT, "--results", str(tmp_path), "-o", str(tmp_path / "out.csv"))
    assert code == 2 and "-o writes the flight of a local run" in err
    code, _, err = run(capsys, "track", "camera:0", "--results", str(tmp_path))
    assert code == 2 and "camera:0: no such file or folder" in err
    (tmp_path / "a_file").write_text("")
    code, _, err = run(capsys, "evaluate", DATASETS[2], "--results", str(tmp_path / "a_file"))
    assert code == 2 and "is a file: give a folder" in err
    (tmp_path / "truth.json").write_text(json.dumps({"video": "gone.mp4", "frames": []}))  # a flight without its video
    code, _, err = run(capsys, "sweep", "threshold", "--lo", "0.5", "--hi", "0.9", str(tmp_path))
    assert code == 2 and f"{tmp_path / 'truth.json'} must name its video, a file beside it" in err
