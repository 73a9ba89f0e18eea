"""Live runs of the CLI in this process, fed from a thread and ended by Ctrl-C, with no sleeps.

``listen`` and ``track --listen`` write ``LABEL: listening; Ctrl-C ends the run with its summary`` on
stderr once their Ctrl-C handler is in place, and a CAN source takes the frames still waiting on the bus
when it stops: so :func:`run_live` feeds the run once that line is out and presses Ctrl-C as soon as the
feeding is done, and the run's summary has every frame fed. Everything else a test waits for is an
event (a line on stderr, :class:`StderrLines`) or a state (:func:`wait_until`); a limit only turns a
hang into a failure that says what never happened.
"""

from __future__ import annotations

import os
import re
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import can

from online_backlash.cli import main
from online_backlash.cli._live import CTRL_C_READY

#: Seconds after which a wait that never ends fails the test (a hang guard, not a timing).
LIMIT_S = 120.0


def wait_until(condition: Callable[[], Any], what: str, limit_s: float = LIMIT_S) -> None:
    """Wait for a state another process or a file holds (nothing to be told by): look every 10 ms."""
    deadline = time.monotonic() + limit_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"never happened within {limit_s} s: {what}")
        time.sleep(0.01)


def kill_mid_work(pid: int, condition: Callable[[], Any], what: str, limit_s: float = LIMIT_S) -> None:
    """SIGKILL process ``pid`` in a state where ``condition()`` holds: the process is stopped (SIGSTOP)
    while the condition is looked at, so it cannot move on between the look and the kill; if the
    condition does not hold yet it goes on (SIGCONT) for 10 ms. Fails if it ends first."""
    deadline = time.monotonic() + limit_s
    while True:
        os.kill(pid, signal.SIGSTOP)
        try:
            hit = condition()
        except BaseException:
            os.kill(pid, signal.SIGCONT)
            raise
        if hit:
            os.kill(pid, signal.SIGKILL)
            return
        os.kill(pid, signal.SIGCONT)
        if time.monotonic() > deadline:
            raise AssertionError(f"never happened within {limit_s} s: {what}")
        time.sleep(0.01)


class StderrLines:
    """``sys.stderr`` while in use: everything still goes to the stream it replaced (``capsys`` sees it),
    and a thread can wait for a line (``\\n`` or the status line's ``\\r``) that matches a pattern."""

    def __init__(self) -> None:
        self.through = sys.stderr
        self.text = ""
        self.ended = False  # the run is over: nothing more will come
        self._changed = threading.Condition()

    def __enter__(self) -> StderrLines:
        sys.stderr = self  # type: ignore[assignment]
        return self

    def __exit__(self, *exc: object) -> None:
        sys.stderr = self.through
        self.end()

    def write(self, text: str) -> int:
        self.through.write(text)
        with self._changed:
            self.text += text
            self._changed.notify_all()
        return len(text)

    def flush(self) -> None:
        self.through.flush()

    def isatty(self) -> bool:
        return False

    def __getattr__(self, name: str) -> Any:
        return getattr(self.through, name)

    def end(self) -> None:
        with self._changed:
            self.ended = True
            self._changed.notify_all()

    def lines(self) -> list[str]:
        return re.split(r"[\r\n]", self.text)

    def wait_for(self, pattern: str, count: int = 1, limit_s: float = LIMIT_S) -> list[re.Match[str]]:
        """Wait until ``count`` lines match ``pattern`` (``re.search``); their matches. Fails if the run ends first."""

        def found() -> list[re.Match[str]]:
            return [m for m in map(re.compile(pattern).search, self.lines()) if m]

        with self._changed:
            self._changed.wait_for(lambda: len(found()) >= count or self.ended, limit_s)
            matches = found()
        assert len(matches) >= count, f"stderr never had {count} lines matching {pattern!r}:\n{self.text[-3000:]}"
        return matches


def send_frames(channel: str, frames: list[can.Message]) -> None:
    """Put ``frames`` on a virtual CAN bus (each is queued at every listener when ``send`` returns)."""
    with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx:
        for frame in frames:
            tx.send(frame)


def run_live(argv: list[Any], feed: Callable[[StderrLines], None] = lambda _: None) -> int:
    """Run the CLI (``argv``) here while a thread, once the run handles Ctrl-C, calls ``feed(stderr)``
    and then presses Ctrl-C (SIGINT to this process); the run's exit code. A failure of ``feed`` is
    raised after the run. A Ctrl-C that comes when the run is over (it ended by itself, or failed
    before it listened) meets a handler that ignores it, not pytest's."""
    failure: list[BaseException] = []
    before = signal.signal(signal.SIGINT, lambda *_: None)
    try:
        with StderrLines() as stderr:

            def drive() -> None:
                try:
                    stderr.wait_for(re.escape(CTRL_C_READY))
                    feed(stderr)
                except BaseException as exc:  # reported after the run
                    failure.append(exc)
                finally:
                    os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C ends the live run with its summary

            driver = threading.Thread(target=drive)
            driver.start()
            try:
                code = main([str(a) for a in argv])
            finally:
                stderr.end()
                driver.join()
    finally:
        signal.signal(signal.SIGINT, before)
    if failure:
        raise failure[0]
    return code
