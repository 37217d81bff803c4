"""An installed copy (pip install ., not -e) has no source checkout to find the page and the samples
in: they ship inside its packages, all under the one import namespace `signpose`."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
# What building the wheel reads: the packages and the folders pyproject.toml packs into them.
SOURCES = ("pyproject.toml", "README.md", "app", "pipeline", "static", "sample_images/library", "sample_images/scenes",
           "sample_images/flights")


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The folder the packages are installed to, laid out as `pip install .` lays them: by setuptools'
    build_py, which building the wheel runs (a second or so, where a real install into a venv takes
    half a minute), over a copy of the checkout so that nothing is written into it."""
    source, lib = tmp_path_factory.mktemp("source"), tmp_path_factory.mktemp("site-packages")
    for name in SOURCES:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy(REPO / name, source / name)
    subprocess.run([sys.executable, "-c", "from setuptools import setup; setup()", "-q", "build_py",
                    "--build-lib", str(lib)], cwd=source, check=True, capture_output=True, timeout=120)
    return lib


def run_installed(lib: Path, args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """`python args` importing signpose from `lib` only, run away from the checkout."""
    env = {**os.environ, "PYTHONPATH": str(lib)}
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


SERVE = """
from pathlib import Path
import signpose.app
from fastapi.testclient import TestClient
from signpose.app.server import create_app
from signpose.app.workspace import WorkspaceConfig
assert Path(signpose.app.__file__).is_relative_to({lib!r}), signpose.app.__file__  # not the checkout
# the server answers requests addressed to a loopback host only
with TestClient(create_app(WorkspaceConfig(state_dir=Path("state"))), base_url="http://127.0.0.1") as client:
    page, script = client.get("/"), client.get("/app.js")
    print(page.status_code, "<html" in page.text.lower(), script.status_code, len(client.get("/api/images").json()["images"]),
          [f["name"] for f in client.get("/api/flights").json()["flights"]])
"""


@pytest.mark.slow
def test_an_installed_copy_serves_the_page_with_the_sample_library_scenes_and_flight(installed, tmp_path):
    result = run_installed(installed, ["-c", SERVE.format(lib=str(installed))], tmp_path)
    assert result.returncode == 0, result.stderr
    # the page, its script, the 12 sample scenes and the sample flight (viser then says it stopped)
    assert result.stdout.splitlines()[0].split() == ["200", "True", "200", "12", "['corridor.mp4']"], result.stdout


def test_an_installed_copy_recognizes_with_the_sample_library_by_default(installed, tmp_path):
    scene = installed / "signpose" / "pipeline" / "sample_images" / "scenes" / "scene_002.jpg"
    result = run_installed(installed, ["-m", "signpose.app.cli", "recognize", str(scene), "--json"], tmp_path)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["label"] == "security_compound"


def test_an_installed_copy_has_one_namespace(installed, tmp_path):
    """signpose owns `signpose` only: `app` and `pipeline` are other projects' names."""
    assert sorted(p.name for p in installed.iterdir() if not p.name.endswith(".egg-info")) == ["signpose"]
    probe = "import importlib.util as u; print([u.find_spec(n) is None for n in ('app', 'pipeline')])"
    result = run_installed(installed, ["-c", probe], tmp_path)
    assert result.stdout.strip() == "[True, True]", result.stdout + result.stderr
