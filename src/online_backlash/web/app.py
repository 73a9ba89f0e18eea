"""The Flask application of ``online-backlash serve``: the fleet table and each gearbox's plots.

Routes (all GET; nothing writes):

* ``/``: the fleet table and, per gearbox, its wear plot and latest identified backlash loop;
  the page reloads itself every ``refresh_s`` seconds (``<meta http-equiv="refresh">``).
* ``/gearbox/<id>/wear.png``: :func:`~online_backlash.web.figures.wear_png`.
* ``/gearbox/<id>/characteristic.png``: the loop of the newest estimate with the parameters of
  eq. (1); 404 if no estimate carries them.
* ``/metrics``: every gearbox's gauges in the Prometheus text format (:mod:`.metrics`).
"""

from __future__ import annotations

import os
import time

from flask import Flask, Response, abort, render_template

from ..errors import HistoryError, InvalidParameterError
from ..history.alarms import DEFAULT_MAX_AGE_H
from ..history.report import wear_report
from ..history.store import HistoryStore
from .figures import characteristic_png, latest_characteristic, wear_png
from .fleet import fleet_rows
from .metrics import metrics_text
from .readonly import open_read_only

#: Seconds between the page's own reloads.
DEFAULT_REFRESH_S = 30.0


def create_app(
    db: str | os.PathLike[str] | HistoryStore,
    refresh_s: float = DEFAULT_REFRESH_S,
    max_age_h: float = DEFAULT_MAX_AGE_H,
) -> Flask:
    """The fleet page over the store ``db`` (a path or URL, opened read-only, or an open store).

    ``refresh_s`` is the reload period of the page, seconds (> 0); ``max_age_h`` the age in
    calendar hours after which a gearbox's state is ``unknown`` (as ``history --max-age-h``).
    """
    if not refresh_s > 0:
        raise InvalidParameterError(f"the refresh period must be positive seconds, got {refresh_s!r}")
    store = db if isinstance(db, HistoryStore) else open_read_only(db)
    app = Flask(__name__)

    @app.get("/")
    def fleet() -> str:
        rows = fleet_rows(store, max_age_h)
        loops = {r.gearbox: _has_loop(r.gearbox) for r in rows}
        return render_template(
            "fleet.html",
            rows=rows,
            loops=loops,
            store=store.name,
            refresh_s=refresh_s,
            now=time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()),
        )

    def _has_loop(gearbox_id: str) -> bool:
        return latest_characteristic(store.estimates(gearbox_id)) is not None

    @app.get("/gearbox/<path:gearbox_id>/wear.png")
    def wear(gearbox_id: str) -> Response:
        try:
            report = wear_report(store, gearbox_id, max_age_h=max_age_h)
        except HistoryError:
            abort(404)
        return _png(wear_png(report))

    @app.get("/gearbox/<path:gearbox_id>/characteristic.png")
    def characteristic(gearbox_id: str) -> Response:
        if store.find_gearbox(gearbox_id) is None:
            abort(404)
        found = latest_characteristic(store.estimates(gearbox_id))
        if found is None:
            abort(404)
        estimate, params = found
        return _png(characteristic_png(gearbox_id, estimate, params))

    @app.get("/metrics")
    def metrics() -> Response:
        from prometheus_client import CONTENT_TYPE_LATEST

        body = metrics_text(store, max_age_h)
        return Response(body, content_type=CONTENT_TYPE_LATEST, headers={"Cache-Control": "no-store"})

    return app


def _png(data: bytes) -> Response:
    return Response(data, mimetype="image/png", headers={"Cache-Control": "no-store"})
