"""Plots of a fitted backlash (matplotlib, written to a file; nothing is shown on screen)."""

from __future__ import annotations

import os

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
