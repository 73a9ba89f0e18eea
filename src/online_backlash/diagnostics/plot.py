"""The residual before and after the loop, against time and load angle, and its spectrum."""

from __future__ import annotations

import os

import numpy as np

from ._causal import sample_period_s
from .diagnosis import Diagnosis
from .residuals import profile, time_spectrum


def plot_diagnosis(diagnosis: Diagnosis, path: str | os.PathLike[str], title: str | None = None) -> None:
    """Write a PNG: the residual against time, against load angle, and its spectrum (deg), before and
    after the loop; then one panel per term added, the residual just before and after it against the
    variable the term acts along (load angle, velocity, torque or acceleration, time), with its
    held-out gain."""
    from matplotlib.figure import Figure  # no pyplot: no global backend or figure registry to manage

    d = diagnosis
    before, after = d.residual_before_deg, d.residual_after_deg
    period = sample_period_s(d.time_s)
    step = max(1, before.size // 20000)
    per_step = d.step_residuals()
    rows = 3 + (len(per_step) + 1) // 2
    fig = Figure(figsize=(9, 3.2 * rows))
    grid = fig.add_gridspec(rows, 2)
    axes = [fig.add_subplot(grid[i, :]) for i in range(3)]
    ax = axes[0]
    ax.plot(d.time_s[::step], before[::step], ".", ms=1, alpha=0.5, label=f"before (RMS {d.rms_before_deg:.4f} deg)")
    ax.plot(d.time_s[::step], after[::step], ".", ms=1, alpha=0.5, label=f"after (RMS {d.rms_after_deg:.4f} deg)")
    ax.set_xlabel("time, s")
    ax.set_ylabel("simulation residual, deg")
    ax.legend(loc="upper right", markerscale=8)
    ax = axes[1]
    ax.plot(d.load_deg[::step], before[::step], ".", ms=1, alpha=0.5, label="before")
    ax.plot(d.load_deg[::step], after[::step], ".", ms=1, alpha=0.5, label="after")
    ax.set_xlabel("load angle, deg")
    ax.set_ylabel("simulation residual, deg")
    ax.legend(loc="upper right", markerscale=8)
    ax = axes[2]
    for r, label in ((before, "before"), (after, "after")):
        f, amp = time_spectrum(r, period)
        ax.loglog(f[1:], amp[1:], label=label)
    # white noise of RMS s has amplitude s * sqrt(2 df / fs) per bin
    ax.axhline(
        d.noise.floor_deg * np.sqrt(2 * (f[1] - f[0]) * period),
        color="k",
        ls=":",
        lw=1,
        label=f"white noise at the floor ({d.noise.floor_deg:.4f} deg RMS)",
    )
    ax.set_xlabel("frequency, Hz")
    ax.set_ylabel("amplitude per bin, deg")
    ax.legend(loc="upper right")
    for i, (s, b, a) in enumerate(per_step):  # each term against the variable it acts along
        ax = fig.add_subplot(grid[3 + i // 2, i % 2])
        name, unit, values = d.axis(s)
        for r, label, colour in ((b, "before", "C0"), (a, "after", "C1")):
            p = profile(r, values, name, unit)
            ax.plot(values[::step], r[::step], ".", ms=1, alpha=0.3, color=colour)
            ax.plot(p.centers, p.mean_deg, "-", lw=1.5, color=colour, label=f"{label} (bin means)")
        gain = s.detection.score.heldout_gain
        ax.set_title(f"step {s.number}: {s.effect.name}, held-out gain {gain:.0%}", fontsize=9)
        ax.set_xlabel(f"{name}, {unit}")
        ax.set_ylabel("residual, deg")
        ax.legend(loc="upper right", fontsize=7)
    names = ", ".join(s.effect.name for s in d.steps) or "none"
    fig.suptitle(title or f"residual before / after; terms added: {names}")
    fig.tight_layout()
    fig.savefig(os.fspath(path), dpi=110)
