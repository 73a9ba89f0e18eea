"""Fit a recorded log: read it, refer the motor angle to the load side, run an estimator.

The thin layer between the CLI and the estimators: it returns plain results with units in
their names and never prints.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .estimators import VorosBacklash
from .stream import SampleChunk, refer_to_load

ARCMIN_PER_DEG = 60.0


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
    report = BacklashReport(
        method="batch",
        samples=int(len(chunk)),
        backlash_deg=est.backlash_,
        c_left_deg=est.c_left_,
        c_right_deg=est.c_right_,
        m_left=est.m_left_,
        m_right=est.m_right_,
        residual_rms_deg=est.residual_rms_,
        extra={"n_iter": est.n_iter_},
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
