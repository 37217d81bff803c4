"""Running the `signpose` command line from a test: by its `main` in the test's own process (starting
Python and importing OpenCV for each run costs about half a second of CPU), or as a process of its own
where the process is what is tested (what C libraries write to its stderr, signals, pipes)."""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

from signpose.app.cli import main

ROOT = Path(__file__).resolve().parents[2]


def signpose(*args: object, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """`signpose ARGS` run by the console script's `main` in this process, in `cwd`: its exit code and
    what it printed on stdout and stderr (Python's: not what C libraries write to the process' own)."""
    out, err = io.StringIO(), io.StringIO()
    with (contextlib.chdir(cwd), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err),
          unchanged_environment()):
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:   # argparse's refusals and --help
            code = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1
    return subprocess.CompletedProcess(args, code, out.getvalue(), err.getvalue())


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
