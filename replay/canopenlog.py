"""Recorded CAN logs of CANopen servo drives (every format python-can's ``LogReader`` reads), decoded with the drive's EDS/DCF.

The file handling of :class:`~online_backlash.replay.canlog.CanLog` (directories of raw logs in
name order, ``.gz``, truncated files, ``skip_bad``, ``realtime``) with the frame rules of
:func:`~online_backlash.codecs.canopen.canopen_pipeline`: synchronous TPDOs that follow one SYNC
are one sample, timestamped at the SYNC; event-driven TPDOs (254, 255) are paired in time as the
DBC path pairs two messages. The live :class:`~online_backlash.drivers.canopen.CanopenSource`
feeds the same pipeline, so a raw log recorded live replays to the same samples and counters.
"""

from __future__ import annotations

import os
from typing import Any

from online_backlash.codecs.canopen import CanopenLayout, canopen_pipeline
from online_backlash.codecs.pairing import CanPipeline

from .canlog import CanLog


class CanopenLog(CanLog):
    """A recorded CAN log (or a directory of them) of CANopen drives as a :class:`~online_backlash.stream.SampleSource`.

    Parameters
    ----------
    path : path
        A python-can log (``.asc``, ``.blf``, ``.log``, ``.trc``, ``.mf4`` ...; ``.gz`` too) or a directory of them.
    eds : path
        EDS or DCF of the motor node.
    node : int
        Node-ID of the motor drive (its 0x6064 is the motor angle).
    **where
        ``load_node``, ``load_eds``, ``load_subindex``, ``motor_cpr``, ``load_cpr``: where the load angle is and the
        counts per revolution (:meth:`~online_backlash.codecs.canopen.CanopenLayout.from_files`).
    period_s : float, optional
        Nominal SYNC (or event timer) period, seconds, for gap detection (learnt if None).
    max_skew_s : float
        Event-driven TPDOs: the largest time between the motor and the load value of one sample, seconds.
    strict : bool
        Raise at the first corrupt frame instead of counting it.
    skip_bad, realtime
        See :class:`~online_backlash.replay.canlog.CanLog`.

    Attributes
    ----------
    layout : CanopenLayout
        The two encoder objects, their PDOs, the SYNC COB-ID.
    counters : CanCounters
        Reconcile at the end of iteration (see :mod:`~online_backlash.codecs.canopen`).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        eds: str | os.PathLike[str],
        node: int,
        *,
        period_s: float | None = None,
        max_skew_s: float = 1e-3,
        strict: bool = False,
        skip_bad: bool = False,
        realtime: bool = False,
        **where: Any,
    ) -> None:
        self.layout = CanopenLayout.from_files(eds, node, **where)
        self._frame_args = (period_s, max_skew_s, strict)
        self._setup(path, skip_bad, realtime)

    def _new_pipeline(self) -> CanPipeline:
        """A fresh pipeline (SYNC grouping or pairing in time) for one pass over the files."""
        return canopen_pipeline(self.layout, *self._frame_args)
