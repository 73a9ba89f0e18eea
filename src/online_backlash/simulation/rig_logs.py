"""A simulated rig (:func:`online_backlash.simulation.rig.simulate_rig`) as CAN frames or serial bytes.

For tests, benchmarks and demos of the adapters without hardware: the frames and bytes are
exactly what :class:`~online_backlash.codecs.dbc.DbcDecoder` and the serial parsers read.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

import can
import numpy as np

from ..codecs.dbc import RIG_DBC, DbcDecoder, FrameEncoder, counts_of
from ..codecs.serialframes import encode_ascii, encode_binary, require_cpr
from .rig import RigRecording, simulate_rig


def rig_can_frames(
    rec: RigRecording, decoder: DbcDecoder, start_s: float = 0.0, skew_s: float = 0.0
) -> Iterator[can.Message]:
    """The frames of every sample, timestamped ``start_s + time_s`` (the load frame ``skew_s`` later when separate)."""
    encoder = FrameEncoder(decoder)
    motor = counts_of(rec.motor_deg, decoder.motor).tolist()
    load = counts_of(rec.load_deg, decoder.load).tolist()
    for i, t in enumerate((rec.time_s + start_s).tolist()):
        frames = encoder.frames(t, motor[i], load[i], i)
        if len(frames) == 2:
            frames[1].timestamp += skew_s
        yield from frames


def rig_serial_records(
    rec: RigRecording, serial_format: str, motor_cpr: float | None = None, load_cpr: float | None = None
) -> Iterator[bytes]:
    """One ``ascii`` line or ``binary`` frame per sample (counts per revolution for ``binary``)."""
    if serial_format == "ascii":
        for t, m, y in zip(rec.time_s.tolist(), rec.motor_deg.tolist(), rec.load_deg.tolist()):
            yield encode_ascii(t, m, y)
        return
    time_us = np.rint(rec.time_s * 1e6).astype(np.int64).tolist()
    motor = np.rint(rec.motor_deg / (360.0 / require_cpr("motor_cpr", motor_cpr))).astype(np.int64).tolist()
    load = np.rint(rec.load_deg / (360.0 / require_cpr("load_cpr", load_cpr))).astype(np.int64).tolist()
    for i in range(len(time_us)):
        yield encode_binary(i, time_us[i], motor[i], load[i])


def write_rig_can_log(
    path: str | os.PathLike[str],
    duration_s: float = 60.0,
    motor_signal: str = "MotorAngle.Count",
    load_signal: str = "LoadAngle.Count",
    start_s: float = 1.7e9,
    **rig: Any,
) -> int:
    """Write a simulated rig as a CAN log (any python-can writer format, by suffix) encoded
    with the shipped ``rig.dbc``; ``rig`` goes to :func:`~online_backlash.simulation.rig.simulate_rig`.
    Returns the number of frames written."""
    rec = simulate_rig(duration_s=duration_s, **rig)
    n = 0
    with can.Logger(os.fspath(path)) as writer:
        for msg in rig_can_frames(rec, DbcDecoder(RIG_DBC, motor_signal, load_signal), start_s, skew_s=5e-5):
            writer.on_message_received(msg)
            n += 1
    return n


def write_rig_serial_capture(
    path: str | os.PathLike[str],
    serial_format: str = "binary",
    duration_s: float = 60.0,
    motor_cpr: float = 2**14,
    load_cpr: float = 2**17,
    **rig: Any,
) -> int:
    """Write a simulated rig as a serial capture (``ascii`` or ``binary``); returns the bytes written."""
    rec = simulate_rig(duration_s=duration_s, **rig)
    data = b"".join(rig_serial_records(rec, serial_format, motor_cpr, load_cpr))
    with open(path, "wb") as f:
        f.write(data)
    return len(data)
