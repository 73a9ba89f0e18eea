"""Fit a recorded log: read it, refer the motor angle to the load side, run an estimator.

The thin layer between the CLI and the estimators: it returns plain results with units in
their names and never prints.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

import numpy as np

from .errors import InvalidParameterError, LogFormatError
from .estimators import BacklashRLS, VorosBacklash
from .stream import SampleChunk, refer_to_load

ARCMIN_PER_DEG = 60.0

#: columns of the estimate-over-time trace (``estimate --trace``), in this order
TRACE_COLUMNS = ("time", "backlash_deg", "backlash_std_deg", "c_left_deg", "c_right_deg", "m_left", "m_right")


@dataclass
class BacklashReport:
    """The result of fitting one log; angles in degrees (load side), as in ``estimate --json``."""

    method: str
    samples: int
    backlash_deg: float
    c_left_deg: float
    c_right_deg: float
    m_left: float
    m_right: float
    residual_rms_deg: float
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_estimator(cls, method: str, samples: int, est: Any, **extra: Any) -> "BacklashReport":
        """The report of a fitted estimator (batch or recursive: the same fitted attributes, degrees)."""
        return cls(
            method=method,
            samples=samples,
            backlash_deg=est.backlash_,
            c_left_deg=est.c_left_,
            c_right_deg=est.c_right_,
            m_left=est.m_left_,
            m_right=est.m_right_,
            residual_rms_deg=est.residual_rms_,
            extra=extra,
        )

    @property
    def backlash_arcmin(self) -> float:
        """The play in arc minutes."""
        return self.backlash_deg * ARCMIN_PER_DEG

    def as_dict(self) -> dict[str, Any]:
        """The JSON contract of ``online-backlash estimate --json`` (more keys may follow)."""
        out = {
            "backlash_deg": self.backlash_deg,
            "backlash_arcmin": self.backlash_arcmin,
            "c_left_deg": self.c_left_deg,
            "c_right_deg": self.c_right_deg,
            "m_left": self.m_left,
            "m_right": self.m_right,
            "samples": self.samples,
            "residual_rms_deg": self.residual_rms_deg,
            "method": self.method,
        }
        out.update(self.extra)
        return out


def fit_batch(chunk: SampleChunk, ratio: float, **params: Any) -> tuple[BacklashReport, VorosBacklash]:
    """Fit :class:`VorosBacklash` (eq. 8-14, then the output-error refinement) to a whole log in memory."""
    u = refer_to_load(chunk.motor_deg, ratio)
    est = VorosBacklash(**params).fit(u, chunk.load_deg)
    return BacklashReport.from_estimator("batch", int(len(chunk)), est, n_iter=est.n_iter_), est


def trace_point(est: BacklashRLS, time_s: float) -> dict[str, float]:
    """The current estimate as one trace row (keys :data:`TRACE_COLUMNS`; degrees, load side)."""
    return {
        "time": float(time_s),
        "backlash_deg": est.backlash_,
        "backlash_std_deg": est.backlash_std_,
        "c_left_deg": est.c_left_,
        "c_right_deg": est.c_right_,
        "m_left": est.m_left_,
        "m_right": est.m_right_,
    }


def fit_recursive(
    chunks: Iterable[SampleChunk],
    ratio: float,
    *,
    every_s: float = 1.0,
    trace: Callable[[dict[str, float]], None] | None = None,
    estimator: BacklashRLS | None = None,
    source: str | os.PathLike[str] = "<stream>",
    **params: Any,
) -> tuple[BacklashReport, BacklashRLS]:
    """Stream a log through :class:`BacklashRLS` chunk by chunk (memory stays flat).

    Parameters
    ----------
    chunks : iterable of SampleChunk
        Consecutive blocks, e.g. ``CsvLog(path).iter_chunks()``; ``after_gap`` is passed on.
    ratio : float
        Gear ratio motor:load (``u = motor_deg / ratio``).
    every_s : float
        With ``trace``, one row per ``every_s`` seconds of data (log time).
    trace : callable, optional
        Called with :func:`trace_point` rows: the first sample at or after each tick
        ``t0 + k every_s`` closes a row with the estimate *before* it, stamped with the time of
        the last sample learned; a final row closes the log. Ticks inside a gap give one row.
    estimator : BacklashRLS, optional
        Continue this estimator (e.g. resumed from a saved state) instead of a new one.
    source : str or PathLike
        Names the log in errors.
    **params
        Settings of a new :class:`BacklashRLS`.

    Returns
    -------
    report : BacklashReport
        ``method="recursive"``; ``extra`` has ``backlash_std_deg`` and ``n_reversals``.
    est : BacklashRLS
    """
    if not every_s > 0:
        raise InvalidParameterError(f"every_s must be > 0, got {every_s!r}")
    est = estimator if estimator is not None else BacklashRLS(**params)
    next_tick: float | None = None
    last_time: float | None = None
    rows_since = 0
    seen = False
    for chunk in chunks:
        if not len(chunk):
            continue
        seen = True
        u = refer_to_load(chunk.motor_deg, ratio)
        t = chunk.time_s
        if trace is None:
            est.learn_many(u, chunk.load_deg, chunk.after_gap, time_s=t, torque_Nm=chunk.torque_Nm)
            continue
        if next_tick is None:
            next_tick = float(t[0]) + every_s
        lo = 0
        while lo < t.size:
            hi = int(np.searchsorted(t, next_tick, side="left"))
            if hi > lo:
                est.learn_many(u[lo:hi], chunk.load_deg[lo:hi], chunk.after_gap[lo:hi], time_s=t[lo:hi], torque_Nm=chunk.torque_Nm[lo:hi])
                last_time = float(t[hi - 1])
                rows_since += hi - lo
            if hi == t.size:
                break
            if rows_since and est.started:
                trace(trace_point(est, last_time))
                rows_since = 0
            while next_tick <= t[hi]:
                next_tick += every_s
            lo = hi
    if not seen:
        raise LogFormatError(source, None, "no data rows")
    est.force_start()  # a log shorter than the warm-up: start on what was buffered
    if trace is not None and (rows_since or last_time is None):
        trace(trace_point(est, last_time if last_time is not None else float("nan")))
    report = BacklashReport.from_estimator(
        "recursive", est.n_samples_seen_, est, backlash_std_deg=est.backlash_std_, n_reversals=est.n_reversals_
    )
    return report, est


def describe(report: BacklashReport, source: str | os.PathLike[str] | None = None) -> str:
    """A short human-readable report with units."""
    lines = []
    if source is not None:
        lines.append(f"log:            {os.fspath(source)}")
    lines += [
        f"method:         {report.method}",
        f"samples:        {report.samples}",
        f"backlash:       {report.backlash_deg:.4f} deg  ({report.backlash_arcmin:.2f} arcmin, load side)",
        f"  left flank:   {report.c_left_deg:.4f} deg from the start position, slope {report.m_left:.5f}",
        f"  right flank:  {report.c_right_deg:.4f} deg from the start position, slope {report.m_right:.5f}",
        f"residual RMS:   {report.residual_rms_deg:.5f} deg",
    ]
    std = report.extra.get("backlash_std_deg")
    if std is not None and np.isfinite(std):
        lines.insert(3 if source is None else 4, f"  std error:    {std:.5f} deg")
    return "\n".join(lines)
