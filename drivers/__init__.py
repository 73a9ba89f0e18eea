"""Live adapters: CAN (python-can + cantools) and serial (pyserial), each a sample Source.

::

    dbc.py           DBC signals -> checked encoder counts (cantools; CRC-8 via crccheck); rig.dbc
    pairing.py       frames -> Samples: pair by counter or time, unwrap, gaps; counters
    can.py           CanSource: Bus + Notifier, raw writer first, then the decoder
    serialframes.py  the ascii and binary (COBS + CRC-16) serial formats, resynchronising parsers
    serial.py        SerialSource: pyserial ``serial_for_url``, bytes captured before parsing
    rawlog.py        raw captures named in time order (python-can writers; verbatim bytes)
    assemble.py, gaps.py, unwrap.py   the shared last checks, gap rule and encoder unwrapping
    simulate.py      the simulated rig as CAN frames or serial bytes (tests, benchmarks, demos)

Recorded logs replay through the same decoders: :mod:`online_backlash.replay.canlog` and
:mod:`online_backlash.replay.serialcapture`.
"""
