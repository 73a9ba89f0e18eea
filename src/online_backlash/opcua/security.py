"""Security of the OPC UA server: the message security, the server's certificate, trusted clients, users.

* **Message security** (``--security``): ``basic256sha256-sign-encrypt`` (the default: the
  Basic256Sha256 policy, every message signed and encrypted), ``basic256sha256-sign``, or ``none``
  (no secure channel: for a test bench on a trusted network only).
* **The server's certificate**: given (``--cert FILE --key FILE``: a DER or PEM X.509 certificate
  and its PEM private key), or made on first run in the PKI folder (``--pki DIR``:
  ``server-cert.der``, ``server-key.pem``; self-signed, for the server's application URI and host
  name, renewed when it expires; asyncua's :func:`~asyncua.crypto.cert_gen.setup_self_signed_certificate`).
* **Trusted clients** (``--trust DIR``): a folder of client application certificates (DER or PEM);
  a client whose certificate is not there, or is expired or not made for its application URI, is
  refused when it opens the secure channel (``BadCertificateUntrusted``). Without the folder any
  client certificate opens a channel; the login still decides.
* **Users**: ``--user NAME`` logs in with the password from the environment variable
  :data:`PASSWORD_ENV` (not the command line, where other users of the machine could read it), as
  ``--mqtt`` takes the broker's; anonymous sessions only with ``--allow-anonymous``. A wrong name
  or password is refused (``BadUserAccessDenied``).

Every session is a plain user (asyncua's ``UserRole.User``): it may browse, read and subscribe;
the address space cannot be changed (adding or deleting nodes is an administrator's service) and
every variable is read-only, so a write is refused (``BadUserAccessDenied``/``BadNotWritable``).
"""

from __future__ import annotations

import hmac
import socket
from pathlib import Path
from typing import Any

from asyncua import Server, ua
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.user_managers import UserManager

from ..errors import InvalidParameterError
from .settings import CERT_FILE, KEY_FILE, OpcuaSecurity, application_uri, default_pki_dir

#: ``--security`` (:data:`.settings.SECURITY_MODES`) -> the asyncua security policy of the endpoint.
SECURITY_POLICIES = {
    "basic256sha256-sign-encrypt": ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
    "basic256sha256-sign": ua.SecurityPolicyType.Basic256Sha256_Sign,
    "none": ua.SecurityPolicyType.NoSecurity,
}


class ReadOnlyUsers(UserManager):
    """asyncua's user manager: the one user with its password, anonymous sessions if allowed; each a plain user."""

    def __init__(self, user: str | None, password: str | None, allow_anonymous: bool) -> None:
        self.user = user
        self.password = password
        self.allow_anonymous = allow_anonymous

    def get_user(
        self, iserver: Any, username: str | None = None, password: str | None = None, certificate: Any = None
    ) -> User | None:
        # ``certificate`` is the secure channel's client certificate, whatever the token; user certificates
        # (X509 tokens) are not offered, so a session without a user name is an anonymous one
        if username is None:
            return User(role=UserRole.User, name="anonymous") if self.allow_anonymous else None
        if self.user is None or self.password is None or username != self.user or password is None:
            return None
        if not hmac.compare_digest(password.encode(), self.password.encode()):
            return None
        return User(role=UserRole.User, name=username)


async def secure(server: Server, settings: OpcuaSecurity) -> str:
    """Apply ``settings`` to ``server`` before it starts; returns where its certificate came from."""
    from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

    server.set_security_policy([SECURITY_POLICIES[settings.mode]])
    tokens: list[type] = [ua.UserNameIdentityToken] if settings.user is not None else []
    if settings.allow_anonymous:
        tokens.append(ua.AnonymousIdentityToken)
    server.set_identity_tokens(tokens)
    await server.set_application_uri(application_uri())
    if settings.mode == "none":
        return "no certificate (--security none)"
    cert, key, origin = await _certificate(settings)
    try:
        await server.load_certificate(str(cert))
        await server.load_private_key(str(key))
    except Exception as exc:  # cryptography's and asyncua's parse errors
        raise InvalidParameterError(
            f"{cert}: not a usable certificate and private key ({type(exc).__name__}: {exc})"
        ) from exc
    if settings.trust_dir is not None:
        from asyncua.crypto.truststore import TrustStore

        store = TrustStore([Path(settings.trust_dir)], [])
        try:
            await store.load()
        except Exception as exc:  # a file there that cryptography cannot read as a certificate
            raise InvalidParameterError(
                f"{settings.trust_dir}: --trust: holds a file that is not a certificate (DER or PEM): {exc}"
            ) from exc
        options = CertificateValidatorOptions.TRUSTED_VALIDATION | CertificateValidatorOptions.PEER_CLIENT
        server.set_certificate_validator(CertificateValidator(options, store))
    return origin


async def _certificate(settings: OpcuaSecurity) -> tuple[Path, Path, str]:
    """The certificate and key files: given, or made (once) in the PKI folder."""
    if settings.cert_file is not None and settings.key_file is not None:
        return Path(settings.cert_file), Path(settings.key_file), f"certificate {settings.cert_file}"
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    folder = Path(settings.pki_dir) if settings.pki_dir is not None else default_pki_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InvalidParameterError(
            f"{folder}: cannot make the PKI folder for the server's certificate ({exc.strerror})"
        ) from exc
    cert, key = folder / CERT_FILE, folder / KEY_FILE
    made = not cert.is_file()
    host = socket.gethostname()
    subject = {"organizationName": "online-backlash", "commonName": f"online-backlash OPC UA server {host}"}
    usage = [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
    await setup_self_signed_certificate(key, cert, application_uri(), host, usage, subject)
    return cert, key, f"certificate {'made in' if made else 'from'} {folder}"
