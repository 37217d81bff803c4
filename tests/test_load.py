"""A short run of bench/load.py: 4 users uploading and reading results for 8 s while a fifth changes
settings, against a real `signpose serve` on 127.0.0.1, and the same with a storm of sweeps beside them.
The 60 s, 16-user figures and the storm's are in docs/benchmarks.md."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests.support.serving import REPO

# bench/load.py runs a real `signpose serve`.
pytestmark = pytest.mark.server


def test_concurrent_users_lose_nothing_and_every_result_matches_its_settings_version():
    run = subprocess.run([sys.executable, "bench/load.py", "--clients", "4", "--seconds", "8", "--json"],
                         cwd=REPO, capture_output=True, text=True, timeout=180)
    # A failed check exits 1 after printing the report (its "examples" say what went wrong); a crash
    # prints none, only a traceback.
    assert run.returncode == 0, f"{run.stderr}\n{run.stdout[-4000:]}"
    report = json.loads(run.stdout.splitlines()[-1])
    assert report["server_errors"] == report["lost_uploads"] == report["mixed_results"] == 0
    assert report["failed"] == report["unfinished"] == 0
    # It did work: results under several settings versions were checked (on a busy machine, 4 in 8 s).
    assert report["results_checked"] >= 3 and report["settings_changes"] >= 10


def test_health_answers_through_a_sweep_storm_and_only_busy_is_a_5xx():
    run = subprocess.run([sys.executable, "bench/load.py", "--clients", "4", "--sweepers", "4", "--seconds", "8",
                          "--json"], cwd=REPO, capture_output=True, text=True, timeout=180)
    assert run.returncode == 0, f"{run.stderr}\n{run.stdout[-4000:]}"
    report = json.loads(run.stdout.splitlines()[-1])
    assert report["server_errors"] == report["failed"] == report["lost_uploads"] == 0
    assert report["sweeps"] >= 1 and report["health_checks"] >= 20 and report["health_p99_ms"] < 1000
