"""The `signpose` console script (pyproject.toml): `signpose.app.cli.main`, with Ctrl-C, SIGTERM and SIGHUP handled
from the first instant.

Importing the CLI (numpy, OpenCV, FastAPI) takes about 0.3 s, before `signpose.app.cli.main` can catch
anything; a Ctrl-C then would end in a traceback. This module imports nothing heavy, so the
script reaches the `try` below at once.
"""

from __future__ import annotations

import contextlib
import signal
import sys
from collections.abc import Iterator

# Besides Ctrl-C's SIGINT: `kill PID` or a supervisor (SIGTERM), the terminal closing (SIGHUP).
STOP_SIGNALS = (signal.SIGTERM, signal.SIGHUP)


class Interrupted(KeyboardInterrupt):
    """A command stopped by a signal, raised where Ctrl-C raises KeyboardInterrupt, so that SIGTERM and SIGHUP take
    Ctrl-C's path: `finally` blocks run, evaluate's worker processes stop after their image. `signum`: the signal;
    `done`: how far the command got, for its message ("57 of 200 images")."""

    def __init__(self, signum: int = signal.SIGINT, done: str = "") -> None:
        super().__init__(signum, done)
        self.signum, self.done = signum, done

    @classmethod
    def after(cls, exc: KeyboardInterrupt, done: str) -> Interrupted:
        """The interruption `exc` (Ctrl-C's plain KeyboardInterrupt is SIGINT's) of a command that got `done` far."""
        return cls(exc.signum if isinstance(exc, cls) else signal.SIGINT, done)


@contextlib.contextmanager
def stopping_on_signals() -> Iterator[list[int]]:
    """Inside, STOP_SIGNALS raise Interrupted in the main thread, and so does SIGINT where it raised KeyboardInterrupt
    (not where it is ignored, as in a shell's background job); after, they do what they did before (the CLI may run
    inside another program, a test). By default STOP_SIGNALS end the process at once: evaluate's worker processes
    went on without it, then waited forever to hand their results to nobody. Yields the signals raised so far, in
    order: a signal whose Interrupted something caught and dropped is still there."""
    raised: list[int] = []

    def raise_interrupted(signum: int, frame: object) -> None:
        raised.append(signum)
        raise Interrupted(signum)

    handled = STOP_SIGNALS + ((signal.SIGINT,) if signal.getsignal(signal.SIGINT) is signal.default_int_handler else ())
    before = {signum: signal.signal(signum, raise_interrupted) for signum in handled}
    try:
        yield raised
    finally:
        for signum, handler in before.items():
            signal.signal(signum, handler)


def interrupted(command: str, exc: KeyboardInterrupt) -> int:
    """Say on stderr that `command` ("signpose evaluate") was stopped by `exc` and how far it got; its exit status,
    the shell's 128 + the signal."""
    stop = exc if isinstance(exc, Interrupted) else Interrupted()
    how = "interrupted" if stop.signum == signal.SIGINT else f"stopped by {signal.Signals(stop.signum).name}"
    with contextlib.suppress(OSError):  # after SIGHUP the terminal may be gone
        print(f"{command}: {how}" + (f" after {stop.done}" if stop.done else ""), file=sys.stderr)
    return 128 + stop.signum


def main() -> int:
    with stopping_on_signals() as raised:
        try:
            from signpose.app.cli import main as cli_main

            # A C extension initialising clears the errors of the Python it calls, a signal's among them: a
            # Ctrl-C in the import was lost 1 time in 100 or so, and the command ran to its end.
            if raised:
                raise Interrupted(raised[-1])
            return cli_main()
        except KeyboardInterrupt as exc:  # while importing or parsing arguments: the command handles its own
            return interrupted("signpose", exc)
        except ImportError as exc:
            # A C extension stopped while it loads (gtsam, imported by the commands that need it) says
            # "initialization failed", from the interruption.
            if not isinstance(exc.__cause__, KeyboardInterrupt):
                raise
            return interrupted("signpose", exc.__cause__)
