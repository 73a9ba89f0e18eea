"""Plots of a fitted backlash (matplotlib, written to a file; nothing is shown on screen)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np


def plot_characteristic(
    u_deg: np.ndarray,
    load_deg: np.ndarray,
    model_deg: np.ndarray,
    path: str | os.PathLike[str],
    title: str = "",
) -> None:
    """Write a PNG of the load angle against the referred motor angle with the fitted characteristic.

    Left: lost motion ``load - u`` against ``u`` (the two flanks appear as two bands one play
    apart) with the model's. Right: the same as ``load`` against ``u`` around the first reversal,
    where the dead band is visible. Angles in degrees, load side.
    """
    u = np.asarray(u_deg, dtype=float)
    y = np.asarray(load_deg, dtype=float)
    m = np.asarray(model_deg, dtype=float)
    y0 = y[0] - u[0]
    from matplotlib.figure import Figure  # no pyplot: no global backend or figure registry to manage

    fig = Figure(figsize=(11, 4.2))
    ax1, ax2 = fig.subplots(1, 2)
    ax1.plot(u, y - u - y0, ".", ms=1, color="0.6", label="measured")
    ax1.plot(u, m - u - y0, "-", lw=0.8, color="C3", label="fitted model")
    ax1.set_xlabel("motor angle / ratio  [deg]")
    ax1.set_ylabel("load - motor/ratio  [deg]")
    ax1.set_title("lost motion over the whole log")
    ax1.legend(loc="best", markerscale=8)
    du = np.sign(np.diff(u))
    nz = np.flatnonzero(du)
    flips = nz[1:][du[nz[1:]] != du[nz[:-1]]] if nz.size > 1 else np.array([], dtype=int)
    centre = int(flips[0]) if flips.size else u.size // 2
    lost = y - u
    band = max(float(np.ptp(lost[max(0, centre - 3000) : centre + 3000])), 1e-3)
    near = np.zeros(u.size, dtype=bool)
    near[max(0, centre - 3000) : centre + 3000] = True
    near &= np.abs(u - u[centre]) < 3 * band
    ax2.plot(u[near], y[near], ".", ms=2, color="0.6", label="measured")
    ax2.plot(u[near], m[near], "-", lw=1.0, color="C3", label="fitted model")
    ax2.set_xlabel("motor angle / ratio  [deg]")
    ax2.set_ylabel("load angle  [deg]")
    ax2.set_title("around a reversal: the dead band")
    ax2.legend(loc="best", markerscale=4)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_hysteresis(curve: Any, path: str | os.PathLike[str], title: str = "", note: str = "") -> None:
    """Write the data-sheet hysteresis curve: torsion angle (arcmin) against torque (N m).

    ``curve`` is a :class:`~online_backlash.load_aware.datasheet.HysteresisCurve`. The samples are
    drawn by engaged flank (left, right, neither), each fitted flank as a line over the torque it
    reached, and the lost motion marked: the two flanks' angles at ``+-T`` joined by an arrow at
    zero torque, labelled with its width and ``T``. ``note`` (e.g. a data licence's attribution)
    is written under the plot.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 5.2))
    ax = fig.subplots()
    q, phi, flank = np.asarray(curve.torque_Nm), np.asarray(curve.torsion_arcmin), np.asarray(curve.flank)
    for side, colour, label in (
        (0, "0.75", "in the dead band"),
        (-1, "C0", "left flank (torque < 0)"),
        (1, "C3", "right flank (torque > 0)"),
    ):
        sel = flank == side
        if sel.any():
            ax.plot(q[sel], phi[sel], ".", ms=1.5, color=colour, label=label)
    for line, colour in ((curve.left, "C0"), (curve.right, "C3")):
        if line is not None:
            offset, slope, (lo, hi) = line
            tq = np.linspace(lo, hi, 2)
            ax.plot(tq, offset + slope * tq, "-", lw=1.4, color=colour)
    if curve.lost_motion_arcmin is not None and curve.left is not None and curve.right is not None:
        t = curve.lost_motion_torque_Nm
        top = curve.right[0] + curve.right[1] * t
        bottom = curve.left[0] - curve.left[1] * t
        for level in (top, bottom):
            ax.axhline(level, color="k", lw=0.6, ls=":")
        for x in (-t, t):
            ax.axvline(x, color="k", lw=0.6, ls=":")
        ax.annotate("", xy=(0.0, top), xytext=(0.0, bottom), arrowprops={"arrowstyle": "<->", "color": "k", "lw": 1.0})
        ax.text(
            0.02,
            0.97,
            f"lost motion {curve.lost_motion_arcmin:.2f} arcmin at +-{t:.3g} N m ({curve.lost_motion_basis})",
            transform=ax.transAxes,
            va="top",
            fontsize=9,
        )
    ax.set_xlabel("torque  [N m]")
    ax.set_ylabel("torsion angle  [arcmin]")
    ax.set_title(f"hysteresis curve: {title}" if title else "hysteresis curve")
    ax.grid(True, lw=0.3)
    ax.legend(loc="lower right", markerscale=6, fontsize=8)
    if note:
        fig.text(0.01, 0.005, note, fontsize=6.5, va="bottom", wrap=True)
    fig.tight_layout(rect=(0, 0.04 if note else 0, 1, 1))
    fig.savefig(path, dpi=110)


def plot_fit(
    chunk: Any,
    ratio: float,
    path: str | os.PathLike[str],
    *,
    rated_torque_Nm: float | None = None,
    title: str = "",
    note: str = "",
    fitted: tuple[Any, Any] | None = None,
    **choice: Any,
) -> Any:
    """Plot the batch fit of a whole log: where the torque path is taken the data-sheet hysteresis curve
    (:func:`plot_hysteresis`), else the backlash characteristic (:func:`plot_characteristic`).

    ``chunk`` is the whole log as a :class:`~online_backlash.stream.SampleChunk`; ``ratio`` motor:load;
    ``fitted`` the ``(report, estimator)`` of :func:`~online_backlash.log_fit.fit_batch` on it, when
    already made (else it is fitted here, with ``choice``: ``play_method`` and ``no_torque_why`` of
    :func:`~online_backlash.log_fit.fit_batch`). Returns that report: the curve's lost motion is the
    report's, computed once, so that a text and the plot show one figure.
    """
    from .load_aware import TorqueBacklash
    from .load_aware.datasheet import DatasheetFigures, hysteresis_curve
    from .log_fit import fit_batch  # the fit, only when a plot is asked for

    report, est = fitted if fitted is not None else fit_batch(chunk, ratio, rated_torque_Nm=rated_torque_Nm, **choice)
    u, y = chunk.referred(ratio)
    if isinstance(est, TorqueBacklash):
        keys = report.as_dict()
        values: dict[str, Any] = {name: keys.get(name) for name in DatasheetFigures.__dataclass_fields__}
        figures = DatasheetFigures(**values)
        plot_hysteresis(hysteresis_curve(est, u, y, chunk.torque_Nm, figures), path, title, note)
    else:
        plot_characteristic(u, y, est.predict(u, y[0]), path, title)
    return report
