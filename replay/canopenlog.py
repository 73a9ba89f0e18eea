"""Recorded CAN logs of CANopen servo drives (every format python-can's ``LogReader`` reads), decoded with the drive's
EDS/DCF.

The file handling of :class:`~online_backlash.replay.canlog.CanLog` (directories of raw logs in
name order, ``.gz``, truncated files, ``skip_bad``, ``realtime``) with the frame rules of
:func:`~online_backlash.codecs.canopen.canopen_pipeline`: synchronous TPDOs that follow one SYNC
are one sample, timestamped at the SYNC; event-driven TPDOs (254, 255) are paired in time as the
DBC path pairs two messages. The live :class:`~online_backlash.drivers.canopen.CanopenSource`
feeds the same pipeline, so a raw log recorded live replays to the same samples and counters.
"""

from __future__ import annotations

from online_backlash.codecs.canopen import CanopenLayout, canopen_pipeline
from online_backlash.codecs.options import CanDecoding, Counts
from online_backlash.codecs.pairing import CanPipeline

from .canlog import CanLog


class CanopenLog(CanLog):
    """A recorded CAN log (or a directory of them) of CANopen drives as a :class:`~online_backlash.stream.SampleSource`.

    Parameters
    ----------
    path : path
        A python-can log (``.asc``, ``.blf``, ``.log``, ``.trc``, ``.mf4`` ...; ``.gz`` too) or a directory of them.
    decoding : CanDecoding
        Its ``canopen``: the motor node's EDS/DCF and node-ID, where the load angle is; its ``max_skew_s``: event-driven
        TPDOs, the largest time between the motor and the load value of one sample, seconds.
    counts, frames, skip_bad, realtime
        See :class:`~online_backlash.replay.canlog.CanLog` (``frames.period_s``: the nominal SYNC or event timer
        period).

    Attributes
    ----------
    layout : CanopenLayout
        The two encoder objects, their PDOs, the SYNC COB-ID.
    counters : CanCounters
        Reconcile at the end of iteration (see :mod:`~online_backlash.codecs.canopen`).
    """

    layout: CanopenLayout

    def _decode_with(self, decoding: CanDecoding, counts: Counts) -> None:
        """The drive's encoder objects and PDOs from its dictionary."""
        self.layout = decoding.canopen_layout(counts)

    def _new_pipeline(self) -> CanPipeline:
        """A fresh pipeline (SYNC grouping or pairing in time) for one pass over the files."""
        return canopen_pipeline(self.layout, *self._frame_args)
