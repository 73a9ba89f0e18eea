"""``online-backlash inspect FILE``: what a file holds, as text and as JSON, for every format."""

from __future__ import annotations

import json

import can
import cantools
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from asammdf import MDF, Signal
from nptdms import ChannelObject, TdmsWriter

from online_backlash.cli import main


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(["inspect", *argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def inspect_json(capsys, *argv: str) -> dict:
    code, out, err = run(capsys, *argv, "--json")
    assert code == 0, err
    return json.loads(out)


@pytest.fixture
def many_channels(tmp_path):
    """An MDF4 with 400 channels in two groups at 1 kHz and 100 Hz, two of them the encoders."""
    t = np.arange(1000) * 1e-3
    slow = np.arange(100) * 1e-2
    fast = [Signal(np.zeros(1000), t, name=f"Sensor_{i:03d}", unit="V") for i in range(300)]
    fast += [Signal(t, t, name="EncMotor_Pos", unit="deg"), Signal(t, t, name="EncLoad_Pos", unit="rad")]
    slow_signals = [Signal(np.zeros(100), slow, name=f"Temp_{i:02d}", unit="degC") for i in range(98)]
    mdf = MDF(version="4.10")
    mdf.append(fast)
    mdf.append(slow_signals)
    path = tmp_path / "rig.mf4"
    mdf.save(path, overwrite=True)
    mdf.close()
    return path


def test_mdf_channels_with_group_unit_rate_and_samples(capsys, many_channels):
    out = inspect_json(capsys, str(many_channels))
    assert out["kind"] == "mdf"
    names = [c["name"] for c in out["channels"] if c["name"] != "time"]
    assert len(names) == 400
    motor = next(c for c in out["channels"] if c["name"] == "EncMotor_Pos")
    assert motor == {
        "name": "EncMotor_Pos",
        "dtype": "float64",
        "samples": 1000,
        "group": 0,
        "unit": "deg",
        "rate_hz": 1000.0,
    }
    temp = next(c for c in out["channels"] if c["name"] == "Temp_07")
    assert (temp["group"], temp["samples"], temp["rate_hz"], temp["unit"]) == (1, 100, 100.0, "degC")


def test_filter_finds_the_two_encoders_among_400_channels(capsys, many_channels):
    code, out, _ = run(capsys, str(many_channels), "--filter", "enc")
    assert code == 0
    lines = out.splitlines()
    assert lines[0] == f"{many_channels}: mdf, 2 channels"
    assert lines[1].split() == ["name", "group", "unit", "type", "samples", "rate_hz"]
    assert [line.split() for line in lines[2:]] == [
        ["EncMotor_Pos", "0", "deg", "float64", "1000", "1000"],
        ["EncLoad_Pos", "0", "rad", "float64", "1000", "1000"],
    ]
    assert [c["name"] for c in inspect_json(capsys, str(many_channels), "--filter", "Temp_0[12]")["channels"]] == [
        "Temp_01",
        "Temp_02",
    ]


def test_tdms_groups_and_channels(capsys, tmp_path):
    path = tmp_path / "rig.tdms"
    with TdmsWriter(str(path)) as writer:
        writer.write_segment(
            [
                ChannelObject(
                    "Encoders", "Motor", np.zeros(500), properties={"unit_string": "deg", "wf_increment": 1e-3}
                ),
                ChannelObject(
                    "Encoders",
                    "Load",
                    np.zeros(500, np.int32),
                    properties={"unit_string": "counts", "wf_increment": 1e-3},
                ),
                ChannelObject("Torque", "Shaft", np.zeros(50), properties={"unit_string": "Nm", "wf_increment": 1e-2}),
            ]
        )
    out = inspect_json(capsys, str(path))
    assert out["kind"] == "tdms"
    assert out["channels"] == [
        {
            "name": "Encoders/Motor",
            "dtype": "float64",
            "samples": 500,
            "group": "Encoders",
            "unit": "deg",
            "rate_hz": 1000.0,
        },
        {
            "name": "Encoders/Load",
            "dtype": "int32",
            "samples": 500,
            "group": "Encoders",
            "unit": "counts",
            "rate_hz": 1000.0,
        },
        {"name": "Torque/Shaft", "dtype": "float64", "samples": 50, "group": "Torque", "unit": "Nm", "rate_hz": 100.0},
    ]


def test_parquet_and_csv_columns_with_types_and_rows(capsys, tmp_path):
    path = tmp_path / "lake.parquet"
    schema = pa.schema(
        [
            pa.field("time_s", pa.float64()),
            pa.field("motor_counts", pa.int64(), metadata={"unit": "counts"}),
            pa.field("note", pa.string()),
        ]
    )
    pq.write_table(
        pa.table([np.arange(30) * 1e-3, np.arange(30), [str(i) for i in range(30)]], schema=schema),
        path,
        row_group_size=7,
    )
    out = inspect_json(capsys, str(path))
    assert out["kind"] == "parquet"
    assert [(c["name"], c["dtype"], c["samples"], c["unit"]) for c in out["channels"]] == [
        ("time_s", "double", 30, None),
        ("motor_counts", "int64", 30, "counts"),
        ("note", "string", 30, None),
    ]
    csv_path = tmp_path / "run.csv"
    csv_path.write_text("time,motor,load,label\n0,1.5,2,a\n0.001,1.6,3,b\n\n0.002,1.7,4,c\n")
    out = inspect_json(capsys, str(csv_path))
    assert out == {
        "path": str(csv_path),
        "kind": "csv",
        "truncated": None,
        "channels": [
            {"name": "time", "dtype": "float64", "samples": 3, "group": None, "unit": None, "rate_hz": None},
            {"name": "motor", "dtype": "float64", "samples": 3, "group": None, "unit": None, "rate_hz": None},
            {"name": "load", "dtype": "int64", "samples": 3, "group": None, "unit": None, "rate_hz": None},
            {"name": "label", "dtype": "string", "samples": 3, "group": None, "unit": None, "rate_hz": None},
        ],
    }


def test_can_log_ids_with_counts_rates_and_dbc_names(capsys, tmp_path):
    dbc = tmp_path / "rig.dbc"
    dbc.write_text(
        'VERSION ""\n\nBS_:\n\nBU_: Rig\n\n'
        'BO_ 256 MotorPos: 8 Rig\n SG_ Count : 0|32@1+ (1,0) [0|0] "counts" Rig\n\n'
        'BO_ 2147484160 LoadPos: 8 Rig\n SG_ Count : 0|32@1+ (1,0) [0|0] "counts" Rig\n'
    )
    database = cantools.database.load_file(str(dbc))
    assert database.get_message_by_name("LoadPos").is_extended_frame
    path = tmp_path / "bus.asc"
    with can.Logger(str(path)) as writer:
        for i in range(100):
            writer.on_message_received(
                can.Message(arbitration_id=0x100, is_extended_id=False, data=bytes(8), timestamp=i * 1e-3)
            )
            if i % 2 == 0:
                writer.on_message_received(
                    can.Message(arbitration_id=0x200, is_extended_id=True, data=bytes(8), timestamp=i * 1e-3)
                )
            if i % 10 == 0:
                writer.on_message_received(
                    can.Message(arbitration_id=0x7FF, is_extended_id=False, data=bytes(2), timestamp=i * 1e-3)
                )
    out = inspect_json(capsys, str(path), "--dbc", str(dbc))
    assert out["kind"] == "can" and out["frames"] == 160
    assert [(i["id"], i["frames"], i["rate_hz"], i["message"]) for i in out["can_ids"]] == [
        ("0x100", 100, 1000.0, "MotorPos"),
        ("0x00000200x", 50, 500.0, "LoadPos"),
        ("0x7FF", 10, 100.0, None),
    ]
    code, text, _ = run(capsys, str(path))
    assert code == 0 and text.splitlines()[0] == f"{path}: CAN log, 160 frames, 3 IDs"


@pytest.mark.parametrize(
    "name, content, reason",
    [
        ("missing.mf4", None, "no such file"),
        ("notes.xyz", b"hello", "inspect reads"),
        ("broken.mf4", b"MDF     4.10    " + bytes(50), "not a readable MDF file"),
        ("broken.parquet", b"PAR1garbage", "truncated Parquet file: it does not end with 'PAR1'"),
        ("broken.tdms", b"TDSn" + bytes(40), "not a TDMS file: it starts with b'TDSn"),
        ("random.tdms", np.random.default_rng(1).bytes(5000), "not a TDMS file: it starts with"),
        ("random.blf", np.random.default_rng(2).bytes(5000), "not a BLF file: it starts with"),
        ("empty.blf", b"", "empty file, not a BLF file"),
        ("empty.csv", b"", "1: empty file"),
    ],
)
def test_bad_files_give_one_error_line_naming_the_file(capsys, tmp_path, name, content, reason):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    code, out, err = run(capsys, str(path))
    assert code == 1 and out == ""
    assert err.startswith(f"error: {path}") and reason in err and len(err.strip().splitlines()) == 1


def _cut(path, share: float = 0.5):
    data = path.read_bytes()
    cut = path.with_name(f"cut_{path.name}")
    cut.write_bytes(data[: int(len(data) * share)])
    return cut


def test_files_cut_short_say_so_in_their_own_terms(capsys, tmp_path, many_channels):
    """Written by their libraries, then cut in half: a TDMS file and a BLF list what is readable and say they are
    truncated (before: npTDMS's log lines, the header's count, exit 0 in silence); an MDF4 and a Parquet file that
    cannot be read say they are cut short, not "unpack requires a buffer of 8 bytes"."""
    n = 4000
    tdms = tmp_path / "bench.tdms"
    with TdmsWriter(tdms) as writer:  # one segment, as one write of LabVIEW's
        writer.write_segment(
            [
                ChannelObject("Enc", name, np.arange(n, dtype=float), properties={"wf_increment": 1e-3})
                for name in ("Motor", "Load")
            ]
        )
    code, out, err = run(capsys, str(_cut(tdms)))
    samples = {c["name"]: c["samples"] for c in json.loads(run(capsys, str(_cut(tdms)), "--json")[1])["channels"]}
    assert code == 0 and "[nptdms" not in err and "Enc/Motor" in out
    assert err.startswith(
        f"warning: {_cut(tdms)}: truncated: the file ends inside its last segment (readable values: Enc/Motor"
    )
    assert 0 < samples["Enc/Motor"] < n and samples["Enc/Load"] < n
    blf = tmp_path / "bus.blf"
    with can.BLFWriter(str(blf)) as writer:
        for i in range(n):
            writer.on_message_received(
                can.Message(timestamp=1.7e9 + i * 1e-3, arbitration_id=0x101, data=i.to_bytes(4, "little"))
            )
    summary = inspect_json(capsys, str(_cut(blf)))
    assert (
        0 < summary["frames"] < n
        and summary["truncated"].startswith("truncated: ")
        and "bytes its header announces" in summary["truncated"]
    )
    assert inspect_json(capsys, str(blf))["truncated"] is None
    code, _, err = run(capsys, str(_cut(many_channels)))
    assert (
        code == 1
        and err
        == f"error: {_cut(many_channels)}: truncated or damaged MDF file: a block it links to runs past its end "
        f"({_cut(many_channels).stat().st_size} bytes)\n"
    )
    table = tmp_path / "lake.parquet"
    pq.write_table(pa.table({"time": np.arange(n) * 1e-3, "motor": np.zeros(n), "load": np.zeros(n)}), table)
    code, _, err = run(capsys, str(_cut(table)))
    assert code == 1 and "truncated Parquet file: it does not end with 'PAR1' as a whole one does" in err
