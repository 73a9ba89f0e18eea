"""A private, throwaway Mosquitto broker on localhost, from Debian's ``mosquitto`` package.

Used by ``conftest.py`` (fixture ``mqtt_broker``): each test that needs one gets its own broker
on a free port, which it may stop and start again on the same port (to test reconnection).
``.ci/run`` installs the package. Standard library only::

    python tests/mqtt_server.py DIR     # runs a broker in the foreground; prints its URL
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path


class MosquittoUnavailable(RuntimeError):
    """The broker binary is missing or the broker did not start."""


def mosquitto_bin() -> str:
    """The ``mosquitto`` executable (PATH, then /usr/sbin)."""
    found = shutil.which("mosquitto") or shutil.which("mosquitto", path="/usr/sbin:/usr/local/sbin")
    if found is None:
        raise MosquittoUnavailable("the Mosquitto broker was not found (mosquitto): install Debian's 'mosquitto' package (.ci/run does)")
    return found


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _accepts(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


class MosquittoBroker:
    """One broker process on ``127.0.0.1:port`` (anonymous, no persistence), restartable on the same port."""

    def __init__(self, folder: Path, port: int | None = None) -> None:
        self.folder = folder
        self.port = port or _free_port()
        self.process: subprocess.Popen | None = None
        folder.mkdir(parents=True, exist_ok=True)
        self.config = folder / "mosquitto.conf"
        self.config.write_text(f"listener {self.port} 127.0.0.1\nallow_anonymous true\npersistence false\nlog_dest stderr\n")

    def url(self, prefix: str) -> str:
        return f"mqtt://127.0.0.1:{self.port}/{prefix}"

    def start(self, timeout_s: float = 10.0) -> None:
        """Start the broker and wait until it accepts connections."""
        log = open(self.folder / "broker.log", "ab")
        self.process = subprocess.Popen([mosquitto_bin(), "-c", str(self.config)], stdout=log, stderr=log)
        log.close()
        deadline = time.monotonic() + timeout_s
        while not _accepts(self.port):
            if self.process.poll() is not None or time.monotonic() > deadline:
                self.stop()
                text = (self.folder / "broker.log").read_text(errors="replace")
                raise MosquittoUnavailable(f"mosquitto did not start on port {self.port}: {text[-2000:]}")
            time.sleep(0.05)

    def stop(self) -> None:
        """Kill the broker (SIGKILL: as a crash, clients see the connection drop) and wait for it."""
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait(timeout=10)
        self.process = None


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python tests/mqtt_server.py DIR")
    broker = MosquittoBroker(Path(sys.argv[1]))
    try:
        broker.start()
    except MosquittoUnavailable as exc:
        sys.exit(f"error: {exc}")
    print(broker.url("PREFIX"), flush=True)
    try:
        assert broker.process is not None
        broker.process.wait()
    except KeyboardInterrupt:
        broker.stop()
