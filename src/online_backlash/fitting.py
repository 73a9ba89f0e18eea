"""Fit a recorded log: read it, refer the motor angle to the load side, run an estimator.

The thin layer between the CLI and the estimators: it returns plain results with units in
their names and never prints. The recursive fit runs the one loop of
:mod:`online_backlash.pipeline`; the columns of its outputs are declared in
:mod:`online_backlash.rows`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .estimators import BacklashRLS, VorosBacklash
from .pipeline import GapPolicy, GapTally, Pipeline, check_every
from .rows import ARCMIN_PER_DEG, REPORT_KEYS, TRACE_COLUMNS, EstimateRow, describe_counts, select, source_counts
from .stream import SampleChunk

__all__ = ["ARCMIN_PER_DEG", "TRACE_COLUMNS", "BacklashReport", "describe", "fit_batch", "fit_recursive"]


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
    def from_estimator(cls, method: str, samples: int, est: Any, **extra: Any) -> BacklashReport:
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
        out = select(REPORT_KEYS, {**vars(self), "backlash_arcmin": self.backlash_arcmin})
        out.update(self.extra)
        return out

    def add_counters(self, counts: Mapping[str, int]) -> BacklashReport:
        """Carry the source's counters (:data:`~online_backlash.rows.COUNTER_KEYS`; ``samples`` stays
        the samples fitted) in ``extra``, hence in :meth:`as_dict` and :func:`describe`; returns self."""
        self.extra.update({k: v for k, v in source_counts(counts).items() if k != "samples"})
        return self


def fit_batch(chunk: SampleChunk, ratio: float, **params: Any) -> tuple[BacklashReport, VorosBacklash]:
    """Fit :class:`VorosBacklash` (eq. 8-14, then the output-error refinement) to a whole log in memory."""
    u, y = chunk.referred(ratio)
    est = VorosBacklash(**{"origin": "first", **params}).fit(u, y)  # encoder zeros are arbitrary
    return BacklashReport.from_estimator("batch", len(chunk), est, n_iter=est.n_iter_, **GapTally.of_chunk(chunk).values()), est


def fit_recursive(
    chunks: Iterable[SampleChunk],
    ratio: float,
    *,
    every_s: float = 1.0,
    trace: Callable[[EstimateRow], None] | None = None,
    estimator: BacklashRLS | None = None,
    source: str | os.PathLike[str] = "<stream>",
    gap_policy: GapPolicy | None = None,
    **params: Any,
) -> tuple[BacklashReport, BacklashRLS]:
    """Stream a log through :class:`BacklashRLS` chunk by chunk (memory stays flat).

    Parameters
    ----------
    chunks : iterable of SampleChunk
        Consecutive blocks, e.g. ``CsvLog(path).iter_chunks()``; ``after_gap``, time and
        torque are passed on.
    ratio : float
        Gear ratio motor:load (``u = motor_deg / ratio``).
    every_s : float
        With ``trace``, one row per ``every_s`` seconds of data (:class:`~online_backlash.pipeline.DataClock`).
    trace : callable, optional
        Called with an :class:`~online_backlash.rows.EstimateRow` every ``every_s`` seconds of
        data once the estimator has started (stamped with the time of the last sample learned),
        and with a final row at the end of the log (:meth:`EstimateRow.trace` gives the
        columns of ``estimate --trace``).
    estimator : BacklashRLS, optional
        Continue this estimator (e.g. resumed from a saved state) instead of a new one.
    source : str or PathLike
        Names the log in errors.
    gap_policy : GapPolicy, optional
        Which gaps the estimator is carried across (default :class:`~online_backlash.pipeline.GapPolicy`).
    **params
        Settings of a new :class:`BacklashRLS`.

    Returns
    -------
    report : BacklashReport
        ``method="recursive"``; ``extra`` has ``backlash_std_deg``, ``n_reversals``, the gap
        figures (:data:`~online_backlash.rows.GAP_KEYS`) and, where the start failed, ``warm_start``
        (how the estimator started and why).
    est : BacklashRLS
    """
    est = estimator if estimator is not None else BacklashRLS(**params)
    check_every(every_s)
    pipeline = Pipeline(est, ratio, every_s if trace is not None else None, gap_policy=gap_policy)  # rows cost time: only for a trace
    for step in pipeline.run(chunks, os.fspath(source)):
        if step.row is not None and trace is not None:
            trace(step.row)
    last = pipeline.finish()
    if last is not None and trace is not None:
        trace(last)
    report = BacklashReport.from_estimator(
        "recursive", est.n_samples_seen_, est, backlash_std_deg=est.backlash_std_, n_reversals=est.n_reversals_,
        **pipeline.gap_tally.values(),
    )
    if est.warm_start_.get("method") == "cold":
        report.extra["warm_start"] = dict(est.warm_start_)
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
    counts = describe_counts(report.as_dict())
    if counts:
        lines.append(f"source:         {counts}")
    warm = report.extra.get("warm_start")
    if warm is not None:
        lines.append(f"warm start:     failed, cold start ({warm.get('reason', 'no reason given')})")
    return "\n".join(lines)
