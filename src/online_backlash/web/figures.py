"""The page's pictures as PNG bytes: the wear plot and the latest identified backlash loop."""

from __future__ import annotations

import io
import tempfile
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from ..errors import InvalidParameterError
from ..history.plot import plot_wear
from ..history.report import WearReport, estimate_dict
from ..history.store import Estimate
from ..model import BacklashParams, simulate_backlash

#: Points per flank of the triangular sweep that traces the loop.
_SWEEP_POINTS = 200


def wear_png(report: WearReport) -> bytes:
    """The wear plot of ``history --plot`` (:func:`~online_backlash.history.plot.plot_wear`) as PNG bytes."""
    with tempfile.TemporaryDirectory(prefix="online-backlash-web-") as folder:
        path = Path(folder) / "wear.png"  # plot_wear writes files; the format follows the suffix
        plot_wear(report, path, dpi=80)
        return path.read_bytes()


def latest_characteristic(estimates: list[Estimate]) -> tuple[Estimate, BacklashParams] | None:
    """The newest estimate carrying all four parameters of eq. (1) (degrees, load side), or None.

    Estimates whose parameters do not form a valid backlash (eq. (1): slopes of one sign,
    non-negative dead band) are passed over.
    """
    for e in reversed(estimates):
        values = (e.m_left, e.c_left_deg, e.m_right, e.c_right_deg)
        if any(v is None for v in values):
            continue
        try:
            params = BacklashParams(e.m_left, e.c_left_deg, e.m_right, e.c_right_deg)  # type: ignore[arg-type]
        except InvalidParameterError:
            continue
        if params.play > 0:
            return e, params
    return None


def characteristic_png(gearbox_id: str, estimate: Estimate, params: BacklashParams) -> bytes:
    """The hysteresis loop of the identified backlash, eq. (1)-(3), as PNG bytes.

    The referred motor angle ``u`` sweeps a triangle over three times the play around the dead
    band; the load angle is :func:`~online_backlash.model.simulate_backlash` of it. Degrees on
    both axes (load side); the title gives the estimate's time (UTC) and the play in arcmin.
    """
    span = 1.5 * params.play
    centre = 0.5 * (params.c_right - params.c_left)
    up = np.linspace(centre - span, centre + span, _SWEEP_POINTS)
    u = np.concatenate([up, up[::-1], up])
    y = simulate_backlash(u, params, x0=params.m_left * (u[0] + params.c_left))
    fig = Figure(figsize=(4.8, 4.0), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(u, y, color="tab:blue", lw=1.5)
    ax.set_xlabel("motor angle / ratio, deg")
    ax.set_ylabel("load angle, deg")
    when = (estimate_dict(estimate)["time"] or "")[:16].replace("T", " ")
    ax.set_title(f"{gearbox_id} at {when} UTC: play {params.play * 60.0:.2f} arcmin", fontsize=9)
    ax.grid(True, alpha=0.3)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=80)
    return buffer.getvalue()
