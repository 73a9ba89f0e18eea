"""The fleet page of ``online-backlash serve``: a read-only web view of a history store.

* :mod:`.readonly`: :func:`open_read_only`, the store opened so that no connection can write.
* :mod:`.fleet`: :func:`fleet_rows`, one table row per gearbox (state, play, trend, forecast).
* :mod:`.figures`: the wear plot and the identified backlash characteristic as PNG bytes.
* :mod:`.app`: :func:`create_app`, the Flask application (GET only; the page refreshes itself).

The page reads the store through :mod:`online_backlash.history` only; no endpoint writes.
"""

from .app import create_app
from .fleet import FleetRow, fleet_rows
from .readonly import open_read_only

__all__ = ["FleetRow", "create_app", "fleet_rows", "open_read_only"]
