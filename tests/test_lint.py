"""pyflakes over the project's Python: an undefined name in a rarely taken error path is a
crash whenever that path is first taken, and an unused import is code nobody reads as dead."""

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_pyflakes_finds_nothing():
    run = subprocess.run([sys.executable, "-m", "pyflakes", "app", "pipeline", "tests", "bench", "tools"],
                         cwd=ROOT, capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr


def test_no_import_uses_the_old_top_level_names():
    """signpose's code lives under `signpose.`; the checkout root on sys.path (pytest's rootdir) would let a
    forgotten `import app` or `from pipeline...` work here and fail in an installed copy."""
    old = re.compile(r"^\s*(?:from|import)\s+(?:app|pipeline)\b|[\"']-m[\"'],\s*[\"'](?:app|pipeline)\.", re.M)
    found = [f"{path.relative_to(ROOT)}:{text.count(chr(10), 0, match.start()) + 1}"
             for path in sorted(ROOT.glob("*/**/*.py")) if "/." not in str(path.relative_to(ROOT))
             for text in [path.read_text(encoding="utf-8")] for match in old.finditer(text)]
    assert not found, f"old import names at {found}"
