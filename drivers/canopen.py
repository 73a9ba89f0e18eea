"""Live CANopen servo drives: the bus and notifier of :class:`~online_backlash.drivers.can.CanSource`, the frame rules
of
:func:`~online_backlash.codecs.canopen.canopen_pipeline` (SYNC grouping, or event-driven TPDOs paired in time).

::

    Bus --Notifier--> RawCanLog (python-can writer, --raw-log DIR)     first: nothing lost
                  \\-> SyncPipeline (the TPDOs after one SYNC -> one sample) -> queue of rows

The raw log replays to the same samples and counters with
:class:`~online_backlash.replay.canopenlog.CanopenLog` (``estimate DIR --eds drive.eds --node 3``).
Nothing here sends on the bus: the SYNC producer (the PLC, a master, or a drive) is someone else.
"""

from __future__ import annotations

from online_backlash.codecs.canopen import CanopenLayout, canopen_pipeline
from online_backlash.codecs.options import CanDecoding, Counts, FrameRules
from online_backlash.codecs.pairing import PerFramePipeline

from .can import CanSource, RowPipeline


class CanopenSource(CanSource):
    """Samples from CANopen drives on a live CAN bus; a :class:`~online_backlash.stream.SampleSource`.

    Parameters
    ----------
    bus, counts, frames, live
        See :class:`~online_backlash.drivers.can.CanSource` (``frames.period_s``: the nominal SYNC or event timer
        period).
    decoding : CanDecoding
        Its ``canopen``: the motor drive's EDS/DCF and node-ID, where the load angle is; its ``max_skew_s``:
        event-driven TPDOs, the largest time between the motor and the load value of one sample, seconds.

    Attributes
    ----------
    layout : CanopenLayout
    counters : CanCounters
        ``frames`` counts every frame the bus delivered; they reconcile after close.
    pipeline : SyncPipeline or FramePipeline
        SYNC grouping, or for event-driven TPDOs the DBC path's pairing in time
        (:func:`~online_backlash.codecs.canopen.canopen_pipeline`).
    """

    layout: CanopenLayout

    def _new_pipeline(self, decoding: CanDecoding, counts: Counts, frames: FrameRules) -> RowPipeline:
        """The drive's TPDOs: grouped by SYNC, or event-driven ones paired in time."""
        self.layout = decoding.canopen_layout(counts)
        pipeline = canopen_pipeline(self.layout, frames.period_s, decoding.max_skew_s, frames.strict)
        self.pipeline: PerFramePipeline = pipeline
        return pipeline
