"""Running the `signpose` command line from a test: by its `main` in the test's own process (starting
Python and importing OpenCV for each run costs about half a second of CPU), or as a process of its own
where the process is what is tested (what C libraries write to its stderr, signals, pipes).

In the test's process a library folder is read once while its files are unchanged (`loaded_library`):
its signs' features, and for the affine fallback their simulated steep views (0.7 s of CPU for the
sample library), are then computed once per settings, as a server computes them once for its library,
not once per command."""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from unittest import mock

from signpose.app import cli
from signpose.app.cli import main
from signpose.pipeline.library import Library, load_library

ROOT = Path(__file__).resolve().parents[2]


def signpose(*args: object, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """`signpose ARGS` run by the console script's `main` in this process, in `cwd`: its exit code and
    what it printed on stdout and stderr (Python's: not what C libraries write to the process' own)."""
    out, err = io.StringIO(), io.StringIO()
    with (contextlib.chdir(cwd), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err),
          unchanged_environment(), mock.patch.object(cli, "load_library", loaded_library)):
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:   # argparse's refusals and --help
            code = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1
    return subprocess.CompletedProcess(args, code, out.getvalue(), err.getvalue())


_LOADED: dict[tuple, Library] = {}


def loaded_library(root: str | Path) -> Library:
    """`load_library(root)`, read again only when a file of the folder has been added, removed or written
    since it was last read here (by name, size and modification time); a folder refused is read again
    each time. The library is read-only for the commands, and its features are cached under the
    settings they were computed with, so a command with other settings computes its own."""
    folder = Path(root).resolve()
    files = sorted(folder.iterdir()) if folder.is_dir() else []
    key = (str(root), folder, tuple((f.name, f.stat().st_size, f.stat().st_mtime_ns) for f in files if f.is_file()))
    if key not in _LOADED:
        _LOADED[key] = load_library(root)
    return _LOADED[key]


@contextlib.contextmanager
def unchanged_environment() -> Iterator[None]:
    """The environment as it was before (`main` sets OpenCV's log level for its worker processes)."""
    before = dict(os.environ)
    try:
        yield
    finally:
        os.environ.clear()
        os.environ.update(before)


def signpose_process(*args: object, cwd: Path = ROOT, timeout: float = 300) -> subprocess.CompletedProcess:
    """`signpose ARGS` in a process of its own, as a user runs it, its output read through pipes."""
    return subprocess.run([sys.executable, "-m", "signpose.app.cli", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout)
