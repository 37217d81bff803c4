"""Static checks over the project's Python, configured in pyproject.toml: ruff (pyflakes' undefined
names and unused imports, syntax errors, bugbear's likely bugs) over everything, and mypy over the
packages. An undefined name or a None passed on in a rarely taken error path is a crash whenever
that path is first taken, and an unused import is code nobody reads as dead."""

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"app": "signpose.app", "pipeline": "signpose.pipeline"}  # folder: import name (pyproject.toml)


def test_ruff_finds_nothing():
    run = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--output-format", "concise",
                          "app", "pipeline", "tests", "bench", "tools"],
                         cwd=ROOT, capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr


def test_mypy_finds_nothing(tmp_path):
    """mypy knows modules by their place on disk and cannot follow pyproject.toml's folder mapping
    (app/ is signpose.app): it checks a tree of links that lays the folders out as their import names."""
    tree = tmp_path / "signpose"
    tree.mkdir()
    for folder in PACKAGES:
        (tree / folder).symlink_to(ROOT / folder, target_is_directory=True)
    run = subprocess.run([sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"),
                          "--cache-dir", str(ROOT / ".mypy_cache"),
                          *[arg for name in PACKAGES.values() for arg in ("-p", name)]],
                         cwd=tmp_path, capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr


def test_no_import_uses_the_old_top_level_names():
    """signpose's code lives under `signpose.`; the checkout root on sys.path (pytest's rootdir) would let a
    forgotten `import app` or `from pipeline...` work here and fail in an installed copy."""
    old = re.compile(r"^\s*(?:from|import)\s+(?:app|pipeline)\b|[\"']-m[\"'],\s*[\"'](?:app|pipeline)\.", re.M)
    found = [f"{path.relative_to(ROOT)}:{text.count(chr(10), 0, match.start()) + 1}"
             for path in sorted(ROOT.glob("*/**/*.py")) if "/." not in str(path.relative_to(ROOT))
             for text in [path.read_text(encoding="utf-8")] for match in old.finditer(text)]
    assert not found, f"old import names at {found}"
