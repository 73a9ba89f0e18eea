"""A private, throwaway Mosquitto broker on localhost, from Debian's ``mosquitto`` package.

Used by ``test_mqtt.py`` (fixture ``mqtt_broker``): each test that needs one gets its own broker
on a free port, which it may stop and start again on the same port (to test reconnection).
``scripts/test`` installs the package. Standard library only::

    python tests/mqtt_server.py DIR     # runs a broker in the foreground; prints its URL
"""

from __future__ import annotations

import getpass
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from free_port import PortTaken, on_a_free_port


class MosquittoUnavailable(RuntimeError):
    """The broker binary is missing or the broker did not start."""


def mosquitto_bin() -> str:
    """The ``mosquitto`` executable (PATH, then /usr/sbin)."""
    found = shutil.which("mosquitto") or shutil.which("mosquitto", path="/usr/sbin:/usr/local/sbin")
    if found is None:
        raise MosquittoUnavailable(
            "the Mosquitto broker was not found (mosquitto): install Debian's 'mosquitto' package (scripts/test does)"
        )
    return found


@dataclass(frozen=True)
class BrokerCertificates:
    """A private CA and a server certificate for 127.0.0.1 signed by it (PEM files), from ``openssl``."""

    ca: Path
    server_cert: Path
    server_key: Path

    @classmethod
    def make(cls, folder: Path) -> BrokerCertificates:
        folder.mkdir(parents=True, exist_ok=True)
        ca, ca_key = folder / "ca.pem", folder / "ca.key"
        cert, key, request = folder / "server.pem", folder / "server.key", folder / "server.csr"
        ext = folder / "san.ext"
        ext.write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
        openssl = shutil.which("openssl") or "openssl"
        quiet = {"check": True, "capture_output": True}
        subprocess.run(
            [
                openssl,
                "req",
                "-x509",
                "-newkey",
                "rsa:2048",
                "-nodes",
                "-days",
                "2",
                "-subj",
                "/CN=test CA",
                "-keyout",
                str(ca_key),
                "-out",
                str(ca),
            ],
            **quiet,
        )
        subprocess.run(
            [
                openssl,
                "req",
                "-newkey",
                "rsa:2048",
                "-nodes",
                "-subj",
                "/CN=127.0.0.1",
                "-keyout",
                str(key),
                "-out",
                str(request),
            ],
            **quiet,
        )
        subprocess.run(
            [
                openssl,
                "x509",
                "-req",
                "-in",
                str(request),
                "-CA",
                str(ca),
                "-CAkey",
                str(ca_key),
                "-CAcreateserial",
                "-days",
                "2",
                "-extfile",
                str(ext),
                "-out",
                str(cert),
            ],
            **quiet,
        )
        return cls(ca, cert, key)


class MosquittoBroker:
    """One broker process on ``127.0.0.1:port`` (anonymous, no persistence), restartable on the same port.

    ``port`` is None until the first :meth:`start` finds a free one (another, if a process takes it first)."""

    def __init__(
        self, folder: Path, tls: BrokerCertificates | None = None, users: dict[str, str] | None = None
    ) -> None:
        self.folder = folder
        self.port: int | None = None
        self.process: subprocess.Popen | None = None
        self.tls = tls
        folder.mkdir(parents=True, exist_ok=True)
        # run as whoever runs the tests (as root, mosquitto would switch to the user 'mosquitto' and lose the test's
        # files)
        self._settings = ["persistence false", "log_dest stderr", f"user {getpass.getuser()}"]
        if tls is not None:  # TLS on this listener: the server certificate signed by the test CA
            self._settings += [f"cafile {tls.ca}", f"certfile {tls.server_cert}", f"keyfile {tls.server_key}"]
        if users:  # logins only, from a password file written by mosquitto_passwd
            passwords = folder / "passwords"
            for i, (user, password) in enumerate(users.items()):
                create = ["-c"] if i == 0 else []
                subprocess.run(
                    [
                        shutil.which("mosquitto_passwd") or "mosquitto_passwd",
                        *create,
                        "-b",
                        str(passwords),
                        user,
                        password,
                    ],
                    check=True,
                )
            self._settings += ["allow_anonymous false", f"password_file {passwords}"]
        else:
            self._settings.append("allow_anonymous true")
        self.config = folder / "mosquitto.conf"
        self.log = folder / "broker.log"

    def url(self, prefix: str, user: str | None = None) -> str:
        login = f"{user}@" if user else ""
        return f"{'mqtts' if self.tls else 'mqtt'}://{login}127.0.0.1:{self.port}/{prefix}"

    def start(self) -> None:
        """Start the broker and wait until it listens: again on its port, or the first time on a free one."""
        try:
            if self.port is None:
                on_a_free_port(self._start_on)
            else:
                self._start_on(self.port)
        except PortTaken as exc:
            raise MosquittoUnavailable(str(exc)) from exc

    def _start_on(self, port: int, timeout_s: float = 60.0) -> None:
        binary = mosquitto_bin()
        logged_before = self.log.stat().st_size if self.log.exists() else 0
        self.config.write_text("\n".join([f"listener {port} 127.0.0.1", *self._settings]) + "\n")
        with open(self.log, "ab") as log:  # the broker writes it; this process closes its copy at once
            self.process = subprocess.Popen([binary, "-c", str(self.config)], stdout=log, stderr=log)
        # ready when it says so ("mosquitto version X running", after it has bound its port): a connection
        # accepted on the port could be another process's
        deadline = time.monotonic() + timeout_s
        while " running\n" not in self._logged(logged_before):
            if self.process.poll() is not None or time.monotonic() > deadline:
                self.stop()
                text = self._logged(logged_before)
                if "Address already in use" in text:
                    raise PortTaken(f"port {port} was taken before mosquitto could listen on it")
                raise MosquittoUnavailable(f"mosquitto did not start on port {port}: {text[-2000:]}")
            time.sleep(0.01)
        self.port = port

    def _logged(self, offset: int) -> str:
        """What the broker has logged since ``offset`` (bytes into its log)."""
        return self.log.read_bytes()[offset:].decode(errors="replace")

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
