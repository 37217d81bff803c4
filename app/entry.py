"""The `signpose` console script (pyproject.toml): `app.cli.main`, with Ctrl-C handled from the first instant.

Importing the CLI (numpy, OpenCV, FastAPI) takes about 0.3 s, before `app.cli.main` can catch
anything; a Ctrl-C then would end in a traceback. This module imports nothing heavy, so the
script reaches the `try` below at once.
"""

from __future__ import annotations

import sys

EXIT_INTERRUPTED = 130  # the shell's 128 + SIGINT


def main() -> int:
    try:
        from app.cli import main as cli_main

        return cli_main()
    except KeyboardInterrupt:  # while importing or parsing arguments: the command handles its own
        print("signpose: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
