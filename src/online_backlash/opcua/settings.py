"""The settings of the OPC UA server's security, checked before anything starts (no asyncua here: the CLI
builds its parser from these names without loading the OPC UA stack). What they mean: :mod:`.security`."""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass
from pathlib import Path

from ..errors import InvalidParameterError

#: The environment variable holding the password of ``--user``.
PASSWORD_ENV = "ONLINE_BACKLASH_OPCUA_PASSWORD"

#: The values of ``--security`` (:mod:`.security` maps them to asyncua's policies).
SECURITY_MODES = ("basic256sha256-sign-encrypt", "basic256sha256-sign", "none")

#: The files of a certificate made on first run, in the PKI folder.
CERT_FILE, KEY_FILE = "server-cert.der", "server-key.pem"


def default_pki_dir() -> Path:
    """Where a certificate made on first run is kept: ``$XDG_DATA_HOME/online-backlash/opcua``."""
    base = os.environ.get("XDG_DATA_HOME") or os.path.join(os.path.expanduser("~"), ".local", "share")
    return Path(base) / "online-backlash" / "opcua"


def application_uri() -> str:
    """The server's application URI (also in its certificate): ``urn:online-backlash:opcua:HOST``."""
    return f"urn:online-backlash:opcua:{socket.gethostname()}"


@dataclass(frozen=True)
class OpcuaSecurity:
    """How the server is secured (see the module docstring); checked by :meth:`check`."""

    mode: str = "basic256sha256-sign-encrypt"
    cert_file: str | None = None
    key_file: str | None = None
    pki_dir: str | None = None
    trust_dir: str | None = None
    user: str | None = None
    allow_anonymous: bool = False

    def check(self) -> str | None:
        """Raise InvalidParameterError for settings that cannot work; return the password of :attr:`user`."""
        if self.mode not in SECURITY_MODES:
            raise InvalidParameterError(f"--security: expected one of {', '.join(SECURITY_MODES)}, got {self.mode!r}")
        if (self.cert_file is None) != (self.key_file is None):
            raise InvalidParameterError("--cert and --key go together: the server's certificate and its private key")
        for option, path in (("--cert", self.cert_file), ("--key", self.key_file)):
            if path is not None and not os.path.isfile(path):
                raise InvalidParameterError(f"{path}: {option}: no such file")
        if self.trust_dir is not None and not os.path.isdir(self.trust_dir):
            raise InvalidParameterError(f"{self.trust_dir}: --trust: no such folder of client certificates")
        if self.user is None:
            if not self.allow_anonymous:
                raise InvalidParameterError(
                    f"give --user NAME (its password in the environment variable {PASSWORD_ENV}) "
                    "or --allow-anonymous to accept sessions without a login"
                )
            return None
        password = os.environ.get(PASSWORD_ENV)
        if not password:
            raise InvalidParameterError(
                f"--user {self.user}: put its password in the environment variable {PASSWORD_ENV}"
            )
        return password
