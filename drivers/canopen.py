"""Live CANopen servo drives: the bus and notifier of :class:`~online_backlash.drivers.can.CanSource`, the frame rules of
:func:`~online_backlash.codecs.canopen.canopen_pipeline` (SYNC grouping, or event-driven TPDOs paired in time).

::

    Bus --Notifier--> RawCanLog (python-can writer, --raw-log DIR)     first: nothing lost
                  \\-> SyncPipeline (the TPDOs after one SYNC -> one sample) -> queue of rows

The raw log replays to the same samples and counters with
:class:`~online_backlash.replay.canopenlog.CanopenLog` (``estimate DIR --eds drive.eds --node 3``).
Nothing here sends on the bus: the SYNC producer (the PLC, a master, or a drive) is someone else.
"""

from __future__ import annotations

import os
from typing import Any

import can

from online_backlash.codecs.canopen import CanopenLayout, canopen_pipeline
from online_backlash.codecs.pairing import PerFramePipeline

from .can import CanSource


class CanopenSource(CanSource):
    """Samples from CANopen drives on a live CAN bus; a :class:`~online_backlash.stream.SampleSource`.

    Parameters
    ----------
    bus : can.BusABC
        An open bus (:func:`~online_backlash.drivers.can.open_bus`); shut down by :meth:`close` if ``own_bus``.
    eds, node, **where
        The motor drive's EDS/DCF and node-ID; ``load_node``, ``load_eds``, ``load_subindex``, ``motor_cpr``,
        ``load_cpr``: where the load angle is (:meth:`~online_backlash.codecs.canopen.CanopenLayout.from_files`).
    raw_log_dir, raw_format, duration_s, timeout_s, own_bus
        See :class:`~online_backlash.drivers.can.CanSource`.
    period_s : float, optional
        Nominal SYNC (or event timer) period, seconds, for gap detection (learnt if None).
    max_skew_s : float
        Event-driven TPDOs: the largest time between the motor and the load value of one sample, seconds.
    strict : bool
        Raise at the first corrupt frame instead of counting it.

    Attributes
    ----------
    layout : CanopenLayout
    counters : CanCounters
        ``frames`` counts every frame the bus delivered; they reconcile after close.
    pipeline : SyncPipeline or FramePipeline
        SYNC grouping, or for event-driven TPDOs the DBC path's pairing in time
        (:func:`~online_backlash.codecs.canopen.canopen_pipeline`).
    """

    def __init__(
        self,
        bus: can.BusABC,
        eds: str | os.PathLike[str],
        node: int,
        *,
        raw_log_dir: str | os.PathLike[str] | None = None,
        raw_format: str = "blf",
        period_s: float | None = None,
        max_skew_s: float = 1e-3,
        strict: bool = False,
        duration_s: float | None = None,
        timeout_s: float | None = None,
        own_bus: bool = True,
        **where: Any,
    ) -> None:
        try:
            self.layout = CanopenLayout.from_files(eds, node, **where)
        except BaseException:
            if own_bus:
                bus.shutdown()
            raise
        pipeline = canopen_pipeline(self.layout, period_s, max_skew_s, strict)
        self.pipeline: PerFramePipeline = pipeline
        self._listen(bus, pipeline, raw_log_dir, raw_format, duration_s, timeout_s, own_bus)
