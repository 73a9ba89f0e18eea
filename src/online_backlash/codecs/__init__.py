"""Frame rules, stated once: what live transports (:mod:`online_backlash.drivers`) and recorded-log
readers (:mod:`online_backlash.replay`) both apply to the bytes and frames they receive.

::

    dbc.py           DBC signals -> checked encoder counts (cantools; CRC-8 via crccheck); rig.dbc
    blockdecode.py   the same checks and decoding on blocks of frames in numpy arrays
    pairing.py       FramePipeline: frames -> Samples one at a time (pair, unwrap, check, gaps); counters
    canopen.py       CANopen drives: TPDO mapping from the EDS/DCF (canopen), SyncPipeline: a sample per SYNC
    blockpairing.py  BlockPipeline: the same rules on blocks of frames, compiled (tested equal)
    serialframes.py  the ascii and binary (COBS + CRC-16) serial formats, resynchronising parsers
    sample_checks.py the last checks before a sample leaves any source (finite, time order, gaps)
    gaps.py          the one gap rule (counter jumps, steps longer than GAP_PERIODS periods)
    unwrap.py        single-turn encoder counts to multi-turn counts
    units.py         angle and count unit strings (DBC signals and measurement channels)

Nothing here opens a bus, a port or a file, and nothing here imports an estimator.
"""
