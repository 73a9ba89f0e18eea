"""Live transports: a CAN bus (python-can) and a serial port (pyserial), each a
:class:`~online_backlash.stream.SampleSource`.

::

    live.py          LiveSource: the receive loop (stop, duration, timeout) both live sources share
    can.py           CanSource: Bus + Notifier, raw writer first, then the frames decoded in blocks
    canopen.py       CanopenSource: the same bus and notifier, CANopen drives' TPDOs grouped by SYNC
    serial.py        SerialSource: pyserial ``serial_for_url``, bytes captured before parsing
    rawlog.py        raw captures named in time order (python-can writers; verbatim bytes)

The frame rules (DBC decoding, serial framing, pairing, unwrapping, gaps) live in
:mod:`online_backlash.codecs`, which the recorded-log readers (:mod:`online_backlash.replay`)
apply too, so a raw capture replays to the samples seen live. Simulated frames and bytes for
tests and demos: :mod:`online_backlash.simulation.rig_logs`.
"""
