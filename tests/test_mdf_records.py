"""MDF channels viewed in their records (one pass over a channel group) equal asammdf's own reading.

``MdfLog`` reads the motor's channel group once for all its channels and views a plain channel
(byte aligned, little endian, no conversion) where it lies in the records; other channels go
through asammdf. Files written by asammdf with every numeric type, big-endian and converted
channels, invalidation bits, compressed data blocks and fragments that end inside a record are
read back and compared with ``MDF.get`` of the whole file (records whose motor value is marked
invalid are skipped and counted, as ``MDF.get`` leaves them out).
"""

from __future__ import annotations

import can  # before asammdf (see the last test)
import numpy as np
import pytest
from asammdf import MDF, Signal
from measurement_cases import fresh_python

from online_backlash.replay.mdf import MdfLog

N = 1_000
DTYPES = ["<u1", "<i1", "<u2", "<i2", "<u4", "<i4", "<u8", "<i8", "<f4", "<f8", ">i4", ">f8"]


def values(dtype: str, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    kind = np.dtype(dtype)
    if kind.kind == "f":
        return rng.normal(0.0, 50.0, N).astype(dtype)
    info = np.iinfo(kind)
    return rng.integers(max(info.min, -(10**6)), min(info.max, 10**6), N, endpoint=True).astype(dtype)


def write(path, motor, load, compression=0, invalid=False, conversion=None):
    t = np.arange(N) * 1e-3
    mdf = MDF(version="4.10")
    bits = np.arange(N) % 7 == 3 if invalid else None
    mdf.append(
        [
            Signal(np.arange(N, dtype=np.uint16), t, name="Counter"),
            Signal(motor, t, name="M", unit="deg", conversion=conversion, invalidation_bits=bits),
            Signal(np.zeros(N, dtype=np.uint8), t, name="Flag"),
            Signal(load, t, name="L", unit="deg"),
        ]
    )
    mdf.save(path, overwrite=True, compression=compression)
    mdf.close()


def read(path, fragment_bytes):
    with MdfLog(path, columns={"motor": "M", "load": "L"}, fragment_bytes=fragment_bytes) as log:
        chunks = list(log.iter_chunks())
        return [
            np.concatenate([getattr(c, f) for c in chunks]) for f in ("time_s", "motor_deg", "load_deg")
        ], log.counters


def bulk(path):
    """asammdf's reading of the whole file: the motor's valid samples, the load at their times."""
    with MDF(path) as mdf:
        motor, load = mdf.get("M"), mdf.get("L")
        assert np.isin(motor.timestamps, load.timestamps).all()
        return [
            motor.timestamps.astype(float),
            motor.samples.astype(float),
            np.interp(motor.timestamps, load.timestamps, load.samples.astype(float)),
        ]


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("fragment_bytes", [1000, 4 << 20])
def test_every_numeric_type_reads_as_asammdf_reads_it(tmp_path, dtype, fragment_bytes):
    path = tmp_path / "types.mf4"
    write(path, values(dtype, 1), values(dtype, 2))
    got, counters = read(path, fragment_bytes)  # 1000 bytes: fragments end inside records
    expected = bulk(path)
    for a, b in zip(got, expected):
        np.testing.assert_array_equal(a, b)
    assert counters.frames == counters.samples == N


@pytest.mark.parametrize(
    "options",
    [{"compression": 2}, {"compression": 1}, {"invalid": True}, {"conversion": {"a": 0.5, "b": 2.0}}],
    ids=["transposed-deflate", "deflate", "invalidation-bits", "linear-conversion"],
)
def test_compressed_blocks_invalidation_bits_and_conversions_read_as_asammdf_reads_them(tmp_path, options):
    path = tmp_path / "special.mf4"
    write(path, values("<i4", 3), values("<f8", 4), **options)
    got, counters = read(path, 777)
    expected = bulk(path)
    for a, b in zip(got, expected):
        np.testing.assert_array_equal(a, b)
    assert counters.skipped == N - expected[0].size == (N // 7 + (N % 7 > 3) if options.get("invalid") else 0)


def test_the_chunks_do_not_share_the_buffer_the_next_fragment_overwrites(tmp_path):
    """asammdf reads every fragment into one reused buffer: chunks kept until the end still hold their samples."""
    path = tmp_path / "alone.mf4"
    t = np.arange(N) * 1e-3
    mdf = MDF(version="4.10")
    mdf.append([Signal(np.arange(N, dtype=np.float64), t, name="M", unit="deg")])
    mdf.append([Signal(np.arange(N, dtype=np.float64) * 2, t, name="L", unit="deg")])
    mdf.save(path, overwrite=True)
    mdf.close()
    got, _ = read(path, 800)
    np.testing.assert_array_equal(got[1], np.arange(N))
    np.testing.assert_array_equal(got[2], np.arange(N) * 2)


def test_a_bus_logging_mf4_reads_after_an_mdf_file_was_opened_first(tmp_path):
    """In a fresh process, deciding that a .mf4 is bus logging (asammdf imported first) leaves python-can's
    MF4 reader working: asammdf and python-can import each other, and the order decides."""
    path = tmp_path / "bus.mf4"
    with can.Logger(str(path)) as writer:
        for i in range(20):
            writer.on_message_received(can.Message(timestamp=i * 1e-3, arbitration_id=0x100, data=bytes(8)))
    script = (
        "import sys\nfrom online_backlash.replay.mdf import is_bus_logging\n"
        "assert 'can' not in sys.modules and is_bus_logging(sys.argv[1])\n"
        "import can\nprint(sum(1 for _ in can.LogReader(sys.argv[1])))"
    )
    assert fresh_python(script, str(path)) == ["20"]


def test_default_blocks_hold_at_most_half_a_mebibyte_of_records(tmp_path):
    """``estimate`` holds about six blocks at once (read ahead, learned, waiting for the bookkeeping): the default
    fragment of 512 KiB keeps the peak of 10 M samples under issue 31's 300 MB (2 MiB took it to 310 MB)."""
    n = 200_000
    t = np.arange(n) * 1e-3
    path = tmp_path / "long.mf4"
    mdf = MDF(version="4.10")
    mdf.append([Signal(np.sin(t), t, name="M", unit="deg"), Signal(np.cos(t), t, name="L", unit="deg")])
    mdf.save(path, overwrite=True)
    mdf.close()
    with MdfLog(path, columns={"motor": "M", "load": "L"}) as log:
        sizes = [len(chunk) for chunk in log.iter_chunks()]
    assert sum(sizes) == n
    assert max(sizes) <= (1 << 19) // 24  # records of time, motor and load: 24 bytes
