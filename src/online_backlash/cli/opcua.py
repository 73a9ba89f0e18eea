"""``online-backlash opcua --db URL [--endpoint opc.tcp://HOST:PORT]``: the fleet as an OPC UA server."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import signal
import sys
import warnings
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

from ..errors import BacklashWarning, InvalidParameterError
from ._options import add_max_age_option, add_store_option, positive_float

if TYPE_CHECKING:
    from ..history.gauges import GearboxGauges
    from ..history.store import HistoryStore
    from ..opcua.settings import OpcuaSecurity

DEFAULT_ENDPOINT = "opc.tcp://0.0.0.0:4840/online-backlash"


def add_subparser(subparsers: argparse._SubParsersAction) -> None:
    from ..opcua.settings import PASSWORD_ENV, SECURITY_MODES

    parser = subparsers.add_parser(
        "opcua",
        help="serve the fleet's play, state and forecast over OPC UA (read-only) for control rooms and SCADA",
        description="Serve the history store over OPC UA: under Objects/Gearboxes one object per gearbox with its "
        "play (deg, arcmin), standard error, state (ok/warning/alarm/unknown as in history --check), levels, hours to "
        "the limit, time of the last estimate and stiffness, in engineering units; values follow the store as track "
        "writes, and a state change raises an alarm event. Read-only. Stop with Ctrl-C.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    add_store_option(parser)
    parser.add_argument("--endpoint", default=DEFAULT_ENDPOINT, help="where to listen: opc.tcp://HOST:PORT[/PATH]")
    parser.add_argument(
        "--security", choices=tuple(SECURITY_MODES), default="basic256sha256-sign-encrypt", help="message security"
    )
    parser.add_argument(
        "--cert", metavar="FILE", help="the server's certificate (DER or PEM); default: one made on first run in --pki"
    )
    parser.add_argument("--key", metavar="FILE", help="the private key (PEM) of --cert")
    parser.add_argument(
        "--pki",
        metavar="DIR",
        help="where a certificate made on first run is kept (default ~/.local/share/online-backlash/opcua)",
    )
    parser.add_argument(
        "--trust", metavar="DIR", help="a folder of trusted client certificates (DER/PEM); others are refused"
    )
    parser.add_argument(
        "--user",
        metavar="NAME",
        help=f"the user that may log in; its password in the environment variable {PASSWORD_ENV}",
    )
    parser.add_argument("--allow-anonymous", action="store_true", help="also accept sessions without a login")
    parser.add_argument("--poll", type=positive_float, default=2.0, metavar="S", help="read the store every S seconds")
    add_max_age_option(parser)
    parser.set_defaults(func=run)


def check_endpoint(url: str) -> str:
    """``opc.tcp://HOST:PORT[/PATH]`` as given; InvalidParameterError naming it otherwise."""
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme != "opc.tcp" or not parts.hostname or port is None or not 0 < port < 65536:
        raise InvalidParameterError(f"--endpoint: expected opc.tcp://HOST:PORT[/PATH], got {url!r}")
    return url


def run(args: argparse.Namespace) -> int:
    from ..opcua.settings import OpcuaSecurity
    from ..web import open_read_only

    endpoint = check_endpoint(args.endpoint)
    security = OpcuaSecurity(args.security, args.cert, args.key, args.pki, args.trust, args.user, args.allow_anonymous)
    security.check()
    if security.mode == "none" and security.user is not None:
        warnings.warn(
            "--security none: the password of --user crosses the network in plain text", BacklashWarning, stacklevel=1
        )
    if not getattr(args, "debug", False):  # asyncua logs refused connections with their traces: not for a console
        logging.getLogger("asyncua").setLevel(logging.CRITICAL)
    with open_read_only(args.db) as store:
        asyncio.run(_serve(store, endpoint, security, args))
    return 0


async def _serve(store: HistoryStore, endpoint: str, security: OpcuaSecurity, args: argparse.Namespace) -> None:
    from ..opcua.server import PlantServer

    def said(gauges: GearboxGauges) -> None:
        print(f"{gauges.gearbox}: state {gauges.state} ({gauges.state_reason})", flush=True)

    def failed(reason: str | None) -> None:
        if reason is None:
            print(f"{store.name}: read again; the values are current", file=sys.stderr, flush=True)
        else:
            print(
                f"warning: {store.name}: cannot read ({reason}); values kept as uncertain", file=sys.stderr, flush=True
            )

    server = PlantServer(
        store, endpoint, security, poll_s=args.poll, max_age_h=args.max_age_h, on_event=said, on_error=failed
    )
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    try:
        await server.start()
    except OSError as exc:
        raise InvalidParameterError(f"--endpoint {endpoint}: cannot listen there ({exc.strerror or exc})") from exc
    users = f"user {security.user}" if security.user else "no user"
    anonymous = ", anonymous sessions" if security.allow_anonymous else ""
    print(
        f"serving {store.name} read-only over OPC UA on {endpoint} ({security.mode}, {server.certificate}; "
        f"{users}{anonymous}; {len(server.objects)} gearboxes; Ctrl-C stops)",
        flush=True,
    )
    try:
        await server.serve(stop)
    finally:
        with contextlib.suppress(Exception):
            await server.stop()
