"""``online-backlash serve --db URL [--port P] [--host H]``: the read-only fleet page."""

from __future__ import annotations

import argparse
import errno
import signal
import socket
from types import FrameType

from ..errors import InvalidParameterError
from ._options import add_max_age_option, add_store_option, port_type


def add_subparser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "serve",
        help="serve a read-only web page of the fleet: states, play, trend, forecast and plots",
        description="Serve the history store as a web page: the fleet table (gearbox, state, play in arcmin with "
        "its std, trend, forecast date, last seen) and per gearbox the wear plot and the latest identified "
        "backlash loop. The store is opened read-only; the page reloads itself. Stop with Ctrl-C.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    add_store_option(parser)
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0: every interface)")
    parser.add_argument("--port", type=port_type, default=8080, help="TCP port 0-65535 (0: any free one, printed)")
    parser.add_argument("--refresh", type=float, default=30.0, metavar="S", help="the page reloads every S seconds")
    add_max_age_option(parser)
    parser.set_defaults(func=run)


def _stop(_signum: int, _frame: FrameType | None) -> None:
    raise SystemExit(0)


def _listening(host: str, port: int) -> socket.socket:
    """A TCP socket bound to ``host:port`` and listening (werkzeug's address family and address); an address that
    does not resolve or cannot be bound (in use, a privileged port) raises InvalidParameterError naming it."""
    from werkzeug.serving import get_sockaddr, select_address_family

    family = select_address_family(host, port)
    listening = socket.socket(family, socket.SOCK_STREAM)
    try:
        listening.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listening.bind(get_sockaddr(host, port, family))
        listening.listen(128)
    except OSError as exc:
        listening.close()
        hints = {
            errno.EADDRINUSE: ": another program listens there; stop it or give another --port (0: any free port)",
            errno.EACCES: ": ports below 1024 need root; give another --port",
        }
        why = f"{exc.strerror or exc}{hints.get(exc.errno or 0, '')}"
        raise InvalidParameterError(f"cannot listen on {host}:{port}: {why}") from exc
    return listening


def run(args: argparse.Namespace) -> int:
    # imported here: Flask, SQLAlchemy and matplotlib load only for this subcommand
    from werkzeug.serving import make_server

    from ..web import create_app, open_read_only

    with open_read_only(args.db) as store:
        app = create_app(store, refresh_s=args.refresh, max_age_h=args.max_age_h)
        with _listening(args.host, args.port) as listening:  # werkzeug gets the socket: its own bind prints and exits
            server = make_server(args.host, args.port, app, threaded=True, fd=listening.fileno())
        port = server.socket.getsockname()[1]
        signal.signal(signal.SIGTERM, _stop)
        print(f"serving {store.name} read-only on http://{args.host}:{port}/ (Ctrl-C stops)", flush=True)
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            pass
        finally:
            server.server_close()
    return 0
