"""``online-backlash serve --db URL [--port P] [--host H]``: the read-only fleet page."""

from __future__ import annotations

import argparse
import signal
from types import FrameType


def add_subparser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "serve",
        help="serve a read-only web page of the fleet: states, play, trend, forecast and plots",
        description="Serve the history store as a web page: the fleet table (gearbox, state, play in arcmin with "
        "its std, trend, forecast date, last seen) and per gearbox the wear plot and the latest identified "
        "backlash loop. The store is opened read-only; the page reloads itself. Stop with Ctrl-C.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--db", required=True, help="history store: an SQLite file path or postgresql://user@host/dbname")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0: every interface)")
    parser.add_argument("--port", type=int, default=8080, help="TCP port (0: any free port, printed at start)")
    parser.add_argument("--refresh", type=float, default=30.0, metavar="S", help="the page reloads every S seconds")
    parser.add_argument("--max-age-h", type=float, default=168.0, metavar="H", help="a gearbox is 'unknown' when its latest estimate is older than H hours")
    parser.set_defaults(func=run)


def _stop(_signum: int, _frame: FrameType | None) -> None:
    raise SystemExit(0)


def run(args: argparse.Namespace) -> int:
    # imported here: Flask, SQLAlchemy and matplotlib load only for this subcommand
    from werkzeug.serving import make_server

    from ..web import create_app, open_read_only

    with open_read_only(args.db) as store:
        app = create_app(store, refresh_s=args.refresh, max_age_h=args.max_age_h)
        server = make_server(args.host, args.port, app, threaded=True)
        signal.signal(signal.SIGTERM, _stop)
        print(f"serving {store.name} read-only on http://{args.host}:{server.server_port}/ (Ctrl-C stops)", flush=True)
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            pass
        finally:
            server.server_close()
    return 0
