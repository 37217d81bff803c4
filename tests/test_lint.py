"""pyflakes over the project's Python: an undefined name in a rarely taken error path is a
crash on the day that path is taken, and an unused import is code nobody reads as dead."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_pyflakes_finds_nothing():
    run = subprocess.run([sys.executable, "-m", "pyflakes", "app", "pipeline", "tests", "bench", "tools"],
                         cwd=ROOT, capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr
