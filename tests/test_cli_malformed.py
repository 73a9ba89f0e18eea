"""Malformed input at the CLI: every case ends in one line ``error: FILE[:LINE]: reason`` (or an
argparse usage error for a bad option, or a documented ``warning:`` line), the right exit code,
and never a traceback (issue 11, item 7; issue 26, item 3: every subcommand). A report without a
play exits with EXIT_NO_PLAY (3), never 0; a ``warning:`` line may precede its one ``error:`` line.

Each row of :data:`CASES` runs one command in-process through ``main(argv)``. ``{d}`` in an
argument or an expected pattern is the folder of the files made by :func:`files`, ``{db}`` a
fresh history store of the test. The files are written by the libraries people use (pandas,
csv, gzip) or cut from a simulated rig log, not shaped to the reader.
"""

from __future__ import annotations

import argparse
import codecs
import contextlib
import csv
import gzip
import os
import re
import shutil
import socket
import subprocess
import sys
import threading
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from measurement_cases import rig_mdf
from rig_can import RIG_CAN

from online_backlash.cli import main
from online_backlash.cli._output import EXIT_NO_PLAY, run_command
from online_backlash.errors import BacklashWarning
from online_backlash.history.store import HistoryStore
from online_backlash.simulation.rig import simulate_rig

DEMO = Path(__file__).resolve().parents[1] / "src" / "online_backlash" / "data" / "demo_rig_30to1.csv.gz"


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    """The malformed logs, next to a good one (10 s of a 30:1 rig with 0.5 deg of play)."""
    d = tmp_path_factory.mktemp("malformed")
    rec = simulate_rig(duration_s=10.0, ratio=30.0, play_deg=0.5, seed=4)
    rec.write_csv(d / "good.csv")
    lines = (d / "good.csv").read_text().splitlines(keepends=True)
    header, body = lines[0], lines[1:]

    def put(name: str, text: str) -> None:
        (d / name).write_text(text)

    def replace_row(name: str, index: int, row: str) -> None:
        put(name, header + "".join(body[:index]) + row + "".join(body[index + 1 :]))

    put("empty.csv", "")
    put("header.csv", header)
    put("blank.csv", "\n\n\n")
    put("wrongcols.csv", "a,b,c\n1,2,3\n")
    replace_row("text.csv", 4, "0.004,abc,1\n")  # line 6
    replace_row("nan.csv", 4, "0.004,nan,1\n")
    replace_row("inf.csv", 4, "0.004,1,-inf\n")
    replace_row("short.csv", 4, "0.004,1\n")
    replace_row("back.csv", 4, "0.0005,1,1\n")
    data = gzip.compress("".join(lines).encode())
    (d / "trunc.csv.gz").write_bytes(data[: len(data) // 2])
    put("fake.csv.gz", "".join(lines[:50]))  # not gzip at all
    t = np.arange(2000) * 1e-3
    wave = np.sin(2 * np.pi * t)
    put("huge.csv", "time,motor,load\n" + "".join(f"{a},{1e300 * b},{1e300 * b / 30}\n" for a, b in zip(t, wave)))
    put("onerow.csv", header + body[0])
    put("nomotion.csv", "time,motor,load\n" + "".join(f"{a},1.0,2.0\n" for a in t))
    put("noreversal.csv", "time,motor,load\n" + "".join(f"{a},{a * 300},{a * 10}\n" for a in t))
    put("zerotime.csv", header + "".join("0," + row.split(",", 1)[1] for row in body))
    dup = list(body)
    for i in range(100, 200, 10):  # ten rows take the previous row's time
        dup[i + 1] = dup[i].split(",")[0] + "," + dup[i + 1].split(",", 1)[1]
    put("dup.csv", header + "".join(dup))
    put("twice.csv", header + "".join(row + row for row in body))  # a logger that wrote every sample twice
    (d / "binary.csv").write_bytes(np.random.default_rng(0).bytes(3000))
    (d / "folder.csv").mkdir()
    rec.write_csv(d / "de_source.csv")
    import pandas as pd

    pd.read_csv(d / "good.csv").to_csv(d / "german.csv", sep=";", decimal=",", index=False)
    radians = pd.read_csv(d / "good.csv")
    radians[["motor", "load"]] = np.radians(radians[["motor", "load"]])  # the rig's encoder grid, written in radians
    radians.to_csv(d / "radians.csv", index=False)
    pd.read_csv(d / "good.csv").rename(columns={"motor": "motor [rad]"}).to_csv(d / "named_rad.csv", index=False)
    put("run.asc", "date Mon Nov 23 01:00:00.000 pm 2026\nbase hex  timestamps absolute\n")
    import scipy.io

    columns = {"time": rec.time_s, "motor": rec.motor_deg, "load": rec.load_deg}
    scipy.io.savemat(d / "good.mat", {name: values[:, None] for name, values in columns.items()})
    data = (d / "good.mat").read_bytes()
    (d / "trunc.mat").write_bytes(data[: len(data) // 2])
    put("text.h5", "time,motor,load\n0,0,0\n")  # not HDF5 at all
    _files_people_have(d, lines)
    _binary_logs(d, rec)
    put(
        "ragged_rows.csv",
        "time,motor,load\n" + "".join(f"{i / 1000},{i},{i}\n" for i in range(7)) + "0.007,1\n0.008,1,2\n",
    )
    with HistoryStore(d / "wear.db", create=True):  # an empty store, for serve's and history's options
        pass
    with open(d / "zeros.csv", "wb") as f:
        f.truncate(2 << 30)  # 2 GiB of NUL bytes, sparse: no disk used
    (d / "store.db").mkdir()
    from test_canopen import write_eds  # a drive's EDS as the canopen library writes it

    defaults = {
        0x6091: (1, 1),
        0x6092: (1, 1),
    }  # the factor group of canopen's sample drive e35.eds, left at its defaults
    write_eds(d / "feed_default.eds", 3, [(0x6064, 0), (0x60E4, 1)], resolution=None, factor_group=defaults)
    return d


def _files_people_have(d: Path, lines: list[str]) -> None:
    """The good log as loggers and spreadsheets write it: comment lines before the header, a Windows export
    (cp1252, ';', decimal comma, a degree sign in the header), Excel's "Unicode text" (UTF-16, tab, CRLF, .txt)."""
    rows = [line.rstrip("\n").split(",") for line in lines]
    with open(d / "commented.csv", "w", newline="") as f:
        f.write("# logger v2.1\n# serial 0042\n")
        csv.writer(f).writerows(rows)
    with open(d / "windows.csv", "w", encoding="cp1252", newline="") as f:
        writer = csv.writer(f, delimiter=";")
        writer.writerow(["time [s]", "motor [°]", "load [°]"])
        writer.writerows([[cell.replace(".", ",") for cell in row] for row in rows[1:]])
    with codecs.open(str(d / "unicode.txt"), "w", encoding="utf-16") as f:
        csv.writer(f, delimiter="\t", lineterminator="\r\n").writerows(rows)


def _binary_logs(d: Path, rec) -> None:
    """Measurement files and CAN logs written by their libraries, then cut in half, emptied or replaced by random
    bytes."""
    import can
    from nptdms import ChannelObject, TdmsWriter

    from online_backlash.simulation.rig_logs import write_rig_can_log

    with TdmsWriter(d / "bench.tdms") as writer:  # one segment, as one write of LabVIEW's
        writer.write_segment([
            ChannelObject("Enc", name, values, properties={"wf_increment": 1e-3, "unit_string": "deg"})
            for name, values in (("Motor", rec.motor_deg), ("Load", rec.load_deg))
        ])  # fmt: skip
    rig_mdf(d / "rig.mf4", rec, names=("EncMotor", "EncLoad"))
    write_rig_can_log(str(d / "rig.blf"), duration_s=2.0)
    for name in ("bench.tdms", "rig.mf4", "rig.blf"):
        data = (d / name).read_bytes()
        (d / f"half_{name}").write_bytes(data[: len(data) // 2])
    (d / "empty.blf").write_bytes(b"")
    for seed, name in enumerate(("random.tdms", "random.blf", "random.mf4", "random.parquet")):
        (d / name).write_bytes(np.random.default_rng(seed + 10).bytes(5000))
    with can.BLFWriter(str(d / "noframes.blf")):
        pass


@pytest.fixture(scope="module")
def busy_port() -> Iterator[int]:
    """A TCP port on 127.0.0.1 that another program listens on (this socket), for ``serve``."""
    with socket.socket() as other:
        other.bind(("127.0.0.1", 0))
        other.listen(1)
        yield other.getsockname()[1]


@dataclass(frozen=True)
class Case:
    """One malformed input: the argv, the exit code, a pattern the last stderr line must match
    (``error: ...``, argparse's ``... error: argument ...`` or ``warning: ...``), and one for stdout."""

    argv: tuple[str, ...]
    code: int
    err: str
    out: str = ""


E, T, D = ("estimate",), ("track",), ("diagnose",)
R = ("--ratio", "30")
TRACK = ("--ratio", "30", "--db", "{db}", "--gearbox", "g", "--quiet")
SIGNALS = ("--motor-signal", "A.a", "--load-signal", "B.b")
OPCUA = ("opcua", "--db", "{db}", "--allow-anonymous")
INS, H, S = ("inspect",), ("history",), ("serve",)
RIG = tuple(RIG_CAN)
TDMS = ("--columns", "motor=Motor,load=Load")
MF4 = ("--columns", "motor=EncMotor,load=EncLoad")
WINDOWS = ("--columns", "time=time [s],motor=motor [°],load=load [°]")
CAN_LISTEN = (
    "listen",
    "can",
    "--interface",
    "virtual",
    "--channel",
    "malformed-quiet",
    *RIG,
    *R,
    "--raw-log",
    "{d}/raw",
)
SERIAL_LISTEN = ("listen", "serial", "--format", "ascii", *R, "--raw-log", "{d}/raw")

CASES = {
    # -- estimate: the file's content
    "empty file": Case((*E, "{d}/empty.csv", *R), 1, r"error: {d}/empty.csv:1: empty file"),
    "blank lines only": Case((*E, "{d}/blank.csv", *R), 1, r"error: {d}/blank.csv:1: empty file"),
    "header only": Case((*E, "{d}/header.csv", *R), 1, r"error: {d}/header.csv: no data rows"),
    "wrong column names": Case(
        (*E, "{d}/wrongcols.csv", *R),
        1,
        r"error: {d}/wrongcols.csv:1: header has no column \['time', 'motor', 'load'\]",
    ),
    "text in a number column": Case((*E, "{d}/text.csv", *R), 1, r"error: {d}/text.csv:6: not a number"),
    "NaN row": Case((*E, "{d}/nan.csv", *R), 1, r"error: {d}/nan.csv:6: non-finite value in motor"),
    "inf row": Case((*E, "{d}/inf.csv", *R, "--method", "batch"), 1, r"error: {d}/inf.csv:6: non-finite value in load"),
    "short row": Case((*E, "{d}/short.csv", *R), 1, r"error: {d}/short.csv:6: expected 3 columns, got 2"),
    "time goes backwards": Case((*E, "{d}/back.csv", *R), 1, r"error: {d}/back.csv:6: time goes backwards"),
    "bad rows skipped are reported": Case((*E, "{d}/nan.csv", *R, "--skip-bad-rows"), 0, r"^$", r"corrupt 1"),
    "bad rows skipped, in JSON": Case((*E, "{d}/text.csv", *R, "--skip-bad-rows", "--json"), 0, r"^$", r'"corrupt": 1'),
    "truncated .csv.gz": Case(
        (*E, "{d}/trunc.csv.gz", *R), 1, r"error: {d}/trunc.csv.gz:\d+: damaged or truncated file"
    ),
    "plain text named .csv.gz": Case(
        (*E, "{d}/fake.csv.gz", *R), 1, r"error: {d}/fake.csv.gz:1: damaged or truncated file"
    ),
    "values near 1e300": Case((*E, "{d}/huge.csv", *R), 1, r"error: {d}/huge.csv:3: angle beyond 1e\+15 deg"),
    "values near 1e300, batch": Case(
        (*E, "{d}/huge.csv", *R, "--method", "batch"), 1, r"error: {d}/huge.csv:3: angle beyond"
    ),
    "one row": Case((*E, "{d}/onerow.csv", *R), 1, r"error: {d}/onerow.csv: only 1 samples buffered"),
    "no motion": Case((*E, "{d}/nomotion.csv", *R), 1, r"error: {d}/nomotion.csv: .*never reverses"),
    "no reversal, batch": Case(
        (*E, "{d}/noreversal.csv", *R, "--method", "batch"), 1, r"error: {d}/noreversal.csv: .*never reverses"
    ),
    "time all zeros": Case(
        (*E, "{d}/zerotime.csv", *R), 1, r"error: {d}/zerotime.csv:10001: time column 'time' never advances"
    ),
    "duplicated timestamps": Case(
        (*E, "{d}/dup.csv", *R),
        0,
        r"warning: {d}/dup.csv: 10 of 10000 samples repeat the previous sample's time",
        "backlash:",
    ),
    "binary garbage named .csv": Case((*E, "{d}/binary.csv", *R), 1, r"error: {d}/binary.csv:1: not a text CSV file"),
    "folder given as a file": Case((*E, "{d}/folder.csv", *R), 1, r"error: {d}/folder.csv: empty directory"),
    "missing file": Case(
        (*E, "{d}/missing.csv", *R), 1, r"error: {d}/missing.csv: cannot open: no such file or folder"
    ),
    "missing folder": Case((*E, "{d}/raw/", *R), 1, r"error: {d}/raw/: no such file or folder"),
    "unknown format": Case((*E, "{d}/good.xyz", *R), 1, r"error: {d}/good.xyz: unknown log format '\.xyz'"),
    "counts under a degrees header": Case(
        (*E, str(DEMO), *R),
        EXIT_NO_PLAY,
        r"error: .*demo_rig_30to1.csv.gz: no play: not reported: fitted slope 8, not near \+-1 .*units.*--ratio 3.75",
    ),
    "radians under a degrees header": Case(
        (*E, "{d}/radians.csv", *R),
        0,
        r"warning: {d}/radians.csv: the angles step by a grid of radians \(motor 'motor' by 2 pi/16384, "
        r"load 'load' by 2 pi/131072.*give --units rad",
        r"backlash:\s+0.0087 deg",
    ),
    "a header naming radians read as degrees": Case(
        (*E, "{d}/named_rad.csv", *R, "--columns", "motor=motor [rad]"),
        0,
        r"warning: {d}/named_rad.csv: column 'motor \[rad\]' names its unit 'rad', but the motor angles are read as "
        r"deg: give --units rad",
    ),
    # -- estimate: options
    "--columns without =": Case(
        (*E, "{d}/good.csv", *R, "--columns", "time"), 1, r"error: --columns expects role=column pairs.*got 'time'"
    ),
    "--columns unknown role": Case(
        (*E, "{d}/good.csv", *R, "--columns", "speed=v"), 1, r"error: unknown column roles \['speed'\]"
    ),
    "--columns missing column": Case(
        (*E, "{d}/good.csv", *R, "--columns", "motor=enc"), 1, r"error: {d}/good.csv:1: header has no column \['enc'\]"
    ),
    "--every 0": Case(
        (*E, "{d}/good.csv", *R, "--every", "0"), 2, r"error: argument --every: expected a positive number, got '0'"
    ),
    "--every -1": Case(
        (*E, "{d}/good.csv", *R, "--every", "-1"), 2, r"error: argument --every: expected a positive number, got '-1'"
    ),
    "--ratio 0": Case(
        (*E, "{d}/good.csv", "--ratio", "0"),
        2,
        r"error: argument --ratio: expected a finite non-zero number.*; got '0'",
    ),
    "--ratio nan": Case(
        (*E, "{d}/good.csv", "--ratio", "nan"), 2, r"error: argument --ratio: expected a finite non-zero number"
    ),
    "--ratio 1e308": Case(
        (*E, "{d}/good.csv", "--ratio", "1e308"), 2, r"error: argument --ratio: .*<= \|R\| <= 100000; got '1e308'"
    ),
    "--ratio 1e-300": Case((*E, "{d}/good.csv", "--ratio", "1e-300"), 2, r"error: argument --ratio: .*0.0001 <= \|R\|"),
    "--ratio text": Case(
        (*E, "{d}/good.csv", "--ratio", "thirty"), 2, r"error: argument --ratio: expected a finite non-zero number"
    ),
    "--memory-s 0": Case(
        (*E, "{d}/good.csv", *R, "--memory-s", "0"),
        2,
        r"error: argument --memory-s: expected a positive number, got '0'",
    ),
    "--bridge-s -1": Case(
        (*E, "{d}/good.csv", *R, "--bridge-s", "-1"), 2, r"error: argument --bridge-s: expected a number >= 0, got '-1'"
    ),
    "--period -1": Case(
        (*E, "{d}/good.csv", *R, "--period", "-1"), 2, r"error: argument --period: expected a positive number"
    ),
    "--units unknown": Case(
        (*E, "{d}/good.csv", *R, "--units", "furlong"), 2, r"error: argument --units: invalid choice"
    ),
    "--units counts without cpr": Case(
        (*E, "{d}/good.csv", *R, "--units", "counts"),
        1,
        r"error: motor is in encoder counts .*needs a positive motor_cpr",
    ),
    "--motor-cpr negative": Case(
        (*E, "{d}/good.csv", *R, "--units", "counts", "--motor-cpr", "-4096"),
        2,
        r"error: argument --motor-cpr: expected a positive number",
    ),
    "--delimiter two characters": Case(
        (*E, "{d}/good.csv", *R, "--delimiter", ";;"),
        2,
        r"error: argument --delimiter: expected one separator character",
    ),
    "--decimal unknown": Case(
        (*E, "{d}/good.csv", *R, "--decimal", ";"), 2, r"error: argument --decimal: invalid choice"
    ),
    "--delimiter wrong for the file": Case(
        (*E, "{d}/good.csv", *R, "--delimiter", ";"), 1, r"error: {d}/good.csv:1: header has no column"
    ),
    "--trace with batch": Case(
        (*E, "{d}/good.csv", *R, "--method", "batch", "--trace", "{d}/t.csv"),
        1,
        r"error: --trace needs --method recursive",
    ),
    "CAN log, missing DBC": Case(
        (*E, "{d}/run.asc", *R, "--dbc", "{d}/none.dbc", *SIGNALS), 1, r"error: {d}/none.dbc: no such file"
    ),
    "CAN log, no DBC given": Case(
        (*E, "{d}/run.asc", *R), 1, r"error: a CAN log needs dbc, motor_signal and load_signal"
    ),
    "CAN log, a CSV as DBC": Case(
        (*E, "{d}/run.asc", *R, "--dbc", "{d}/good.csv", *SIGNALS), 1, r"error: {d}/good.csv: not a usable DBC file"
    ),
    "German Excel file": Case((*E, "{d}/german.csv", *R), 0, r"^$", r"backlash:\s+0\.\d+ deg"),
    "--debug after the subcommand": Case((*E, "{d}/good.csv", *R, "--debug"), 0, r"^$", r"backlash:"),
    # -- track
    "track: missing file": Case(
        (*T, "{d}/missing.csv", *TRACK), 1, r"error: {d}/missing.csv: (cannot open: )?no such file or folder"
    ),
    "track: empty file": Case((*T, "{d}/empty.csv", *TRACK), 1, r"error: {d}/empty.csv:1: empty file"),
    "track: truncated .csv.gz": Case(
        (*T, "{d}/trunc.csv.gz", *TRACK), 1, r"error: {d}/trunc.csv.gz:\d+: damaged or truncated"
    ),
    "track: time all zeros": Case(
        (*T, "{d}/zerotime.csv", *TRACK), 1, r"error: {d}/zerotime.csv:10001: time column 'time' never advances"
    ),
    "track: no reversal says why": Case(
        (*T, "{d}/noreversal.csv", *TRACK),
        0,
        r"^$",
        r"0 estimates added \(the estimator has not started: .*never reverses",
    ),
    "track: one row says why": Case(
        (*T, "{d}/onerow.csv", *TRACK),
        0,
        r"^$",
        r"1 samples, 0 estimates added \(the estimator has not started: only 1 samples",
    ),
    "track: no motion says why": Case(
        (*T, "{d}/nomotion.csv", *TRACK), 0, r"^$", r"0 estimates added \(the estimator has not started"
    ),
    "track: shorter than --every says why": Case(
        (*T, "{d}/good.csv", *TRACK), 0, r"^$", r"0 estimates added \(less than --every 60 s of data"
    ),
    "track: radians under a degrees header": Case(
        (*T, "{d}/radians.csv", *TRACK, "--every", "1"),
        0,
        r"warning: {d}/radians.csv: the angles step by a grid of radians",
        r"estimates added",
    ),
    "track: --gearbox empty": Case(
        (*T, "{d}/good.csv", *R, "--db", "{db}", "--gearbox", ""),
        2,
        r"error: argument --gearbox: expected a non-empty name",
    ),
    "track: --limit-arcmin -1": Case(
        (*T, "{d}/good.csv", *TRACK, "--limit-arcmin", "-1"),
        1,
        r"error: the limit must be a finite positive angle in arcmin",
    ),
    "track: --every 0": Case(
        (*T, "{d}/good.csv", *TRACK, "--every", "0"), 2, r"error: argument --every: expected a positive number"
    ),
    "track: --debug after the subcommand": Case(
        (*T, "{d}/good.csv", *TRACK, "--every", "1", "--debug"), 0, r"^$", r"estimates added"
    ),
    # -- diagnose
    "diagnose: --plot out.xyz": Case(
        (*D, "{d}/good.csv", *R, "--plot", "{d}/out.xyz"),
        1,
        r"error: {d}/out.xyz: cannot draw a plot as \.xyz; use .*\.png",
    ),
    "diagnose: time all zeros": Case(
        (*D, "{d}/zerotime.csv", *R), 1, r"error: {d}/zerotime.csv:10001: time column 'time' never advances"
    ),
    "diagnose: duplicated timestamps, no numpy warning": Case(
        (*D, "{d}/dup.csv", *R), 0, r"warning: {d}/dup.csv: 10 of 10000 samples repeat"
    ),
    "diagnose: radians under a degrees header": Case(
        (*D, "{d}/radians.csv", *R), 0, r"warning: {d}/radians.csv: the angles step by a grid of radians"
    ),
    "diagnose: --max-terms -1": Case(
        (*D, "{d}/good.csv", *R, "--max-terms", "-1"), 2, r"error: argument --max-terms: expected a number 0\.\."
    ),
    "diagnose: every sample twice": Case(
        (*D, "{d}/twice.csv", *R), 0, r"warning: {d}/twice.csv: 10000 of 20000 samples repeat", r"backlash"
    ),
    "diagnose: --ratio 1e308": Case(
        (*D, "{d}/good.csv", "--ratio", "1e308"),
        2,
        r"error: argument --ratio: .*0.0001 <= \|R\| <= 100000; got '1e308'",
    ),
    "diagnose: --ratio 0.0001 warns": Case(
        (*D, "{d}/good.csv", "--ratio", "0.0001"), 0, r"warning: {d}/good.csv: fitted slope 3.333e-06, not near \+-1"
    ),
    "diagnose: counts under a degrees header warns": Case(
        (*D, str(DEMO), *R), 0, r"warning: .*demo_rig_30to1.csv.gz: fitted slope 8, not near \+-1"
    ),
    "diagnose: values near 1e300": Case((*D, "{d}/huge.csv", *R), 1, r"error: {d}/huge.csv:3: angle beyond"),
    "diagnose: no motion": Case((*D, "{d}/nomotion.csv", *R), 1, r"error: {d}/nomotion.csv: "),
    "diagnose: missing file": Case(
        (*D, "{d}/missing.csv", *R), 1, r"error: {d}/missing.csv: cannot open: no such file or folder"
    ),
    "diagnose: --every 0": Case(
        (*D, "{d}/good.csv", *R, "--every", "0"), 2, r"error: argument --every: expected a positive number"
    ),
    "diagnose: truncated .csv.gz": Case(
        (*D, "{d}/trunc.csv.gz", *R), 1, r"error: {d}/trunc.csv.gz:\d+: damaged or truncated"
    ),
    # -- inspect
    "inspect: missing file": Case(("inspect", "{d}/missing.csv"), 1, r"error: {d}/missing.csv: no such file"),
    "inspect: binary garbage named .csv": Case(
        ("inspect", "{d}/binary.csv"), 1, r"error: {d}/binary.csv:1: not a text CSV file"
    ),
    "inspect: truncated .csv.gz": Case(
        ("inspect", "{d}/trunc.csv.gz"), 1, r"error: {d}/trunc.csv.gz:\d+: damaged or truncated file: it ends here"
    ),
    "inspect: German Excel file": Case(("inspect", "{d}/german.csv"), 0, r"^$", r"csv, 3 columns"),
    "inspect: --delimiter wrong": Case(
        ("inspect", "{d}/german.csv", "--delimiter", "tab"), 0, r"^$", r"csv, 1 columns"
    ),
    # -- history
    "history: --gearbox empty": Case(
        ("history", "--db", "{db}", "--gearbox", " "), 2, r"error: argument --gearbox: expected a non-empty name"
    ),
    "history: no store": Case(("history", "--db", "{db}", "--gearbox", "g"), 1, r"error: no history store at {db}"),
    "history --check: no store": Case(
        ("history", "--db", "{db}", "--gearbox", "g", "--check"),
        3,
        r"^$",
        r"BACKLASH UNKNOWN - error: no history store",
    ),
    "history: --plot out.xyz": Case(
        ("history", "--db", "{db}", "--gearbox", "g", "--plot", "{d}/w.xyz"),
        1,
        r"error: {d}/w.xyz: cannot draw a plot as \.xyz",
    ),
    # -- MATLAB and HDF5 files
    "truncated .mat": Case((*E, "{d}/trunc.mat", *R), 1, r"error: {d}/trunc.mat: not a readable MATLAB file"),
    "text named .h5": Case((*E, "{d}/text.h5", *R), 1, r"error: {d}/text.h5: not an HDF5 file"),
    ".mat: missing variable": Case(
        (*E, "{d}/good.mat", *R, "--columns", "motor=Motor"),
        1,
        r"error: {d}/good.mat: no variable 'Motor' for motor \(closest: \['motor'\]",
    ),
    "inspect: truncated .mat": Case(("inspect", "{d}/trunc.mat"), 1, r"error: {d}/trunc.mat: not a readable MATLAB"),
    "inspect: text named .h5": Case(("inspect", "{d}/text.h5"), 1, r"error: {d}/text.h5: not an HDF5 file"),
    "track: truncated .mat": Case((*T, "{d}/trunc.mat", *TRACK), 1, r"error: {d}/trunc.mat: not a readable MATLAB"),
    # -- opcua (checked before anything listens)
    "opcua: bad endpoint": Case((*OPCUA, "--endpoint", "http://plant:4840"), 1, r"error: --endpoint: expected opc"),
    "opcua: no port": Case((*OPCUA, "--endpoint", "opc.tcp://plant"), 1, r"error: --endpoint: expected"),
    "opcua: no store": Case(OPCUA, 1, r"error: no history store at {db}"),
    "opcua: bad certificate path": Case(
        (*OPCUA, "--cert", "{d}/none.der", "--key", "{d}/none.pem"), 1, r"error: {d}/none.der: --cert: no such file"
    ),
    "opcua: --cert without --key": Case((*OPCUA, "--cert", "{d}/good.csv"), 1, r"error: --cert and --key go together"),
    "opcua: no user, no anonymous": Case(("opcua", "--db", "{db}"), 1, r"error: give --user NAME \(its password in"),
    "opcua: --poll 0": Case((*OPCUA, "--poll", "0"), 2, r"error: argument --poll: expected a positive number"),
    # -- issue 26, item 3: files people have that did not open
    "comment lines before the header": Case((*E, "{d}/commented.csv", *R), 0, r"^$", r"backlash:\s+0\.\d+ deg"),
    "--comment unusable": Case(
        (*E, "{d}/good.csv", *R, "--comment", "1"), 2, r"error: argument --comment: comment must be one character"
    ),
    "a Windows export without --encoding": Case(
        (*E, "{d}/windows.csv", *R, *WINDOWS),
        1,
        r"error: {d}/windows.csv:1: not a text CSV file: not UTF-8 \(byte 0xB0.*--encoding \(e.g. cp1252",
    ),
    "a Windows export with --encoding cp1252": Case(
        (*E, "{d}/windows.csv", *R, *WINDOWS, "--encoding", "cp1252"), 0, r"^$", r"backlash:\s+0\.\d+ deg"
    ),
    "--encoding unknown": Case(
        (*E, "{d}/good.csv", *R, "--encoding", "klingon"),
        2,
        r"error: argument --encoding: unknown text encoding 'klingon'",
    ),
    "Excel's Unicode text (.txt)": Case((*E, "{d}/unicode.txt", *R), 0, r"^$", r"backlash:\s+0\.\d+ deg"),
    "2 GiB of NUL bytes named .csv": Case(
        (*E, "{d}/zeros.csv", *R), 1, r"error: {d}/zeros.csv:1: not a text CSV file: NUL bytes in its first 4096 bytes"
    ),
    # -- wrong numbers, internal errors and library internals
    "a TDMS file cut in half": Case(
        (*E, "{d}/half_bench.tdms", *R, *TDMS),
        1,
        r"error: {d}/half_bench.tdms: truncated: the file ends inside its last segment",
    ),
    "random bytes named .tdms": Case(
        (*E, "{d}/random.tdms", *R, *TDMS),
        1,
        r"error: {d}/random.tdms: not a TDMS file: it starts with b'.*' where a TDMS",
    ),
    "an MDF4 cut in half": Case(
        (*E, "{d}/half_rig.mf4", *R, *MF4), 1, r"error: {d}/half_rig.mf4: truncated or damaged MDF file: a block"
    ),
    "random bytes named .mf4": Case(
        (*E, "{d}/random.mf4", *R, *MF4), 1, r"error: {d}/random.mf4: not an MDF file: it starts with"
    ),
    "random bytes named .parquet": Case(
        (*E, "{d}/random.parquet", *R), 1, r"error: {d}/random.parquet: not a Parquet file: it starts with"
    ),
    "a BLF cut in half": Case(
        (*E, "{d}/half_rig.blf", *R, *RIG),
        1,
        r"error: {d}/half_rig.blf:\d+: truncated: \d+ of the \d+ bytes its header announces",
    ),
    "an empty BLF": Case((*E, "{d}/empty.blf", *R, *RIG), 1, r"error: {d}/empty.blf: empty file, not a BLF file$"),
    "random bytes named .blf": Case(
        (*E, "{d}/random.blf", *R, *RIG), 1, r"error: {d}/random.blf: not a BLF file: it starts with"
    ),
    "a BLF without frames": Case((*E, "{d}/noframes.blf", *R, *RIG), 1, r"error: {d}/noframes.blf: no data rows"),
    "diagnose: comment lines before the header": Case(
        (*D, "{d}/commented.csv", *R, "--max-terms", "0"), 0, r"^$", r"backlash"
    ),
    "diagnose: a TDMS file cut in half": Case(
        (*D, "{d}/half_bench.tdms", *R, *TDMS), 1, r"error: {d}/half_bench.tdms: truncated"
    ),
    "diagnose: an empty BLF": Case(
        (*D, "{d}/empty.blf", *R, *RIG), 1, r"error: {d}/empty.blf: empty file, not a BLF file"
    ),
    "diagnose: 2 GiB of NUL bytes named .csv": Case(
        (*D, "{d}/zeros.csv", *R), 1, r"error: {d}/zeros.csv:1: not a text CSV file: NUL bytes"
    ),
    "diagnose: --encoding unknown": Case(
        (*D, "{d}/good.csv", *R, "--encoding", "klingon"), 2, r"error: argument --encoding: unknown text encoding"
    ),
    "track: Excel's Unicode text (.txt)": Case(
        (*T, "{d}/unicode.txt", *TRACK, "--every", "1"), 0, r"^$", r"estimates added"
    ),
    "track: a BLF cut in half": Case(
        (*T, "{d}/half_rig.blf", *TRACK, *RIG), 1, r"error: {d}/half_rig.blf:\d+: truncated"
    ),
    "track: 2 GiB of NUL bytes named .csv": Case(
        (*T, "{d}/zeros.csv", *TRACK), 1, r"error: {d}/zeros.csv:1: not a text CSV file: NUL bytes"
    ),
    "track: --ratio 1e308": Case(
        (*T, "{d}/good.csv", "--ratio", "1e308", "--db", "{db}", "--gearbox", "g"),
        2,
        r"error: argument --ratio: .*got '1e308'",
    ),
    "track: a Windows export without --encoding": Case(
        (*T, "{d}/windows.csv", *TRACK, *WINDOWS), 1, r"error: {d}/windows.csv:1: not a text CSV file"
    ),
    "an EDS with the feed constant at its default and no 0x608F": Case(
        (*E, "{d}/run.asc", *R, "--eds", "{d}/feed_default.eds", "--node", "3", "--load-cpr", "4096"),
        1,
        r"error: {d}/feed_default.eds: node 3: no counts per revolution in the dictionary \(the feed constant "
        r"0x6092 is 1/1, the unit "
        r"default, and no position encoder resolution 0x608F.*\): give --motor-cpr$",
    ),
    # -- inspect: what is readable, in the file's own terms
    "inspect: rows with fewer fields than the header": Case(
        (*INS, "{d}/ragged_rows.csv"), 1, r"error: {d}/ragged_rows.csv:9: expected 3 columns, got 2$"
    ),
    "inspect: random bytes named .tdms": Case((*INS, "{d}/random.tdms"), 1, r"error: {d}/random.tdms: not a TDMS file"),
    "inspect: random bytes named .blf": Case((*INS, "{d}/random.blf"), 1, r"error: {d}/random.blf: not a BLF file"),
    "inspect: an empty BLF": Case((*INS, "{d}/empty.blf"), 1, r"error: {d}/empty.blf: empty file, not a BLF file"),
    "inspect: a TDMS file cut in half": Case(
        (*INS, "{d}/half_bench.tdms"),
        0,
        r"warning: {d}/half_bench.tdms: truncated: the file ends inside its last segment \(readable values: "
        r"Enc/Motor \d+",
        r"Enc/Motor",
    ),
    "inspect: a BLF cut in half": Case(
        (*INS, "{d}/half_rig.blf"),
        0,
        r"warning: {d}/half_rig.blf: truncated: \d+ of the \d+ bytes",
        r"CAN log, \d+ frames",
    ),
    "inspect: an MDF4 cut in half": Case(
        (*INS, "{d}/half_rig.mf4"), 1, r"error: {d}/half_rig.mf4: truncated or damaged MDF file"
    ),
    "inspect: 2 GiB of NUL bytes named .csv": Case(
        (*INS, "{d}/zeros.csv"), 1, r"error: {d}/zeros.csv:1: not a text CSV file: NUL bytes"
    ),
    "inspect: comment lines before the header": Case((*INS, "{d}/commented.csv"), 0, r"^$", r"csv, 3 columns"),
    "inspect: a Windows export": Case(
        (*INS, "{d}/windows.csv", "--encoding", "cp1252"), 0, r"^$", r"motor \[°\]\s+float64"
    ),
    "inspect: Excel's Unicode text (.txt)": Case((*INS, "{d}/unicode.txt"), 0, r"^$", r"csv, 3 columns"),
    "inspect: --comment unusable": Case((*INS, "{d}/good.csv", "--comment", "."), 2, r"error: argument --comment"),
    # -- history, serve, listen: bad stores, addresses, ports and sources
    "history: a CSV as the store": Case(
        (*H, "--db", "{d}/good.csv", "--gearbox", "g"),
        1,
        r"error: {d}/good.csv is not an online-backlash history store",
    ),
    "history: a folder as the store": Case(
        (*H, "--db", "{d}/store.db", "--gearbox", "g"), 1, r"error: {d}/store.db is a folder, not a history store"
    ),
    "history: an unknown database URL": Case(
        (*H, "--db", "foo://x", "--gearbox", "g"), 1, r"error: unsupported database 'foo'"
    ),
    "history: an unknown gearbox": Case(
        (*H, "--db", "{d}/wear.db", "--gearbox", "nope"), 1, r"error: {d}/wear.db holds no gearbox 'nope'"
    ),
    "serve: no store": Case((*S, "--db", "{db}", "--port", "0"), 1, r"error: no history store at {db}"),
    "serve: a CSV as the store": Case(
        (*S, "--db", "{d}/good.csv", "--port", "0"), 1, r"error: {d}/good.csv is not an online-backlash history store"
    ),
    "serve: an unknown database URL": Case(
        (*S, "--db", "foo://x", "--port", "0"), 1, r"error: unsupported database 'foo'"
    ),
    "serve: --port 99999": Case(
        (*S, "--db", "{d}/wear.db", "--port", "99999"),
        2,
        r"error: argument --port: expected a number 0..65535, got '99999'",
    ),
    "serve: --port -1": Case(
        (*S, "--db", "{d}/wear.db", "--port", "-1"), 2, r"error: argument --port: expected a number 0..65535"
    ),
    "serve: a port in use": Case(
        (*S, "--db", "{d}/wear.db", "--port", "{busy}"),
        1,
        r"error: cannot listen on 127.0.0.1:{busy}: .*another program listens there",
    ),
    "serve: a host that is no address": Case(
        (*S, "--db", "{d}/wear.db", "--host", "256.1.1.1", "--port", "0"), 1, r"error: cannot listen on 256.1.1.1:0: "
    ),
    "serve: --refresh 0": Case(
        (*S, "--db", "{d}/wear.db", "--refresh", "0"), 1, r"error: the refresh period must be positive"
    ),
    "listen: an unknown CAN interface": Case(
        ("listen", "can", "--interface", "nope", "--channel", "x", *RIG, *R, "--raw-log", "{d}/raw"),
        1,
        r"error: cannot open CAN interface 'nope'",
    ),
    "listen: neither DBC nor EDS": Case(
        ("listen", "can", "--interface", "virtual", "--channel", "x", *R, "--raw-log", "{d}/raw"),
        1,
        r"error: listen can decodes frames with --dbc",
    ),
    "listen: a DBC that is not there": Case(
        (
            "listen",
            "can",
            "--interface",
            "virtual",
            "--channel",
            "x",
            "--dbc",
            "{d}/none.dbc",
            *SIGNALS,
            *R,
            "--raw-log",
            "{d}/raw",
        ),
        1,
        r"error: {d}/none.dbc: no such file",
    ),
    "listen: a serial port that is not there": Case(
        (*SERIAL_LISTEN, "--port", "{d}/ttyNONE"), 1, r"error: cannot open serial port '{d}/ttyNONE'"
    ),
    "listen: an unknown serial URL": Case(
        (*SERIAL_LISTEN, "--port", "foo://bar"), 1, r"error: cannot open serial port 'foo://bar': .*protocol 'foo'"
    ),
    "listen: --raw-log a file": Case(
        (*CAN_LISTEN[:-1], "{d}/good.csv", "--duration", "1"), 1, r"error: --raw-log {d}/good.csv: is a file"
    ),
    "listen: --duration -1": Case(
        (*CAN_LISTEN, "--duration", "-1"), 2, r"error: argument --duration: expected a positive number"
    ),
    "listen: --timeout 0": Case(
        (*CAN_LISTEN, "--timeout", "0"), 2, r"error: argument --timeout: expected a positive number"
    ),
    "listen: --ratio 1e308": Case(
        ("listen", "can", "--interface", "virtual", "--channel", "x", *RIG, "--ratio", "1e308", "--raw-log", "{d}/raw"),
        2,
        r"error: argument --ratio",
    ),
    "listen: --mqtt not an MQTT URL": Case(
        (*CAN_LISTEN, "--duration", "1", "--gearbox", "g", "--mqtt", "http://x"),
        1,
        r"error: --mqtt: expected mqtt://HOST:PORT/PREFIX",
    ),
    "listen: a silent bus": Case(
        (*CAN_LISTEN, "--duration", "0.2"), 1, r"error: can malformed-quiet: no samples received"
    ),
}


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """``main(argv)`` in-process: exit code (argparse's SystemExit too), stdout, stderr."""
    try:
        code = main(argv)
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("name", CASES)
def test_malformed_input_gives_one_line_and_no_traceback(name, files, busy_port, tmp_path, capsys):
    case = CASES[name]
    fill = {"d": str(files), "db": str(tmp_path / "wear.db"), "busy": str(busy_port)}
    code, out, err = run_cli([a.format(**fill) for a in case.argv], capsys)
    assert "Traceback" not in err and "Traceback" not in out
    lines = [line for line in err.splitlines() if line.strip()]
    usage = [line for line in lines if line.startswith("usage:") or line.startswith(" ")]
    listening = [line for line in lines if line.endswith(": listening; Ctrl-C ends the run with its summary")]
    messages = [line for line in lines if line not in usage and line not in listening]  # a live run says it listens
    assert code == case.code, err
    errors = [line for line in messages if not line.startswith("warning: ")]
    assert len(errors) <= 1 and messages[: len(messages) - len(errors)] == [
        m for m in messages if m.startswith("warning: ")
    ], err
    pattern = (
        case.err.replace("{d}", re.escape(fill["d"]))
        .replace("{db}", re.escape(fill["db"]))
        .replace("{busy}", fill["busy"])
    )
    assert re.search(pattern, "\n".join(messages)), (
        err
    )  # one line (after argparse's usage, for a bad option; warnings first)
    if code == 1 or (code == EXIT_NO_PLAY and case.argv[0] != "history"):  # history --check: 3 is Nagios' UNKNOWN
        assert messages[-1].startswith("error: ")
    if code == 2:
        assert usage and re.match(
            rf"online-backlash {case.argv[0]}( \w+)?: error: argument ", messages[0]
        )  # listen can: its own prog
    if case.out:
        assert re.search(case.out, out), out


def test_track_counts_a_log_without_estimates_as_read(files, tmp_path, capsys):
    argv = [
        "track",
        str(files / "noreversal.csv"),
        "--ratio",
        "30",
        "--db",
        str(tmp_path / "w.db"),
        "--gearbox",
        "g",
        "--quiet",
    ]
    assert run_cli(argv, capsys)[0] == 0
    code, out, _ = run_cli(argv, capsys)
    assert code == 0 and "already imported" in out


def test_postgresql_without_psycopg_names_the_extra(files, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "psycopg", None)  # as after a plain pip install: import psycopg fails
    for argv in (
        ["history", "--db", "postgresql://rig@localhost/wear", "--gearbox", "g"],
        [
            "track",
            str(files / "good.csv"),
            "--ratio",
            "30",
            "--db",
            "postgresql://rig@localhost/wear",
            "--gearbox",
            "g",
            "--quiet",
        ],
    ):
        code, _, err = run_cli(argv, capsys)
        assert code == 1 and "Traceback" not in err
        assert re.fullmatch(
            r"error: .*postgresql.* needs the driver psycopg, which is not installed; pip install "
            r"'online-backlash\[postgres\]'\n",
            err,
        )


@contextlib.contextmanager
def unwritable(folder: Path):
    """``folder`` made unwritable for this process: immutable (chattr +i) when run as root, else mode 555."""
    if os.geteuid() == 0:
        subprocess.run(["chattr", "+i", str(folder)], check=True)
        try:
            yield
        finally:
            subprocess.run(["chattr", "-i", str(folder)], check=True)
    else:
        folder.chmod(0o555)
        try:
            yield
        finally:
            folder.chmod(0o755)


def test_history_reads_a_store_in_a_read_only_folder(files, tmp_path, capsys):
    folder = tmp_path / "share"
    folder.mkdir()
    db = folder / "wear.db"
    argv = [
        "track",
        str(files / "good.csv"),
        "--ratio",
        "30",
        "--db",
        str(db),
        "--gearbox",
        "g",
        "--every",
        "2",
        "--quiet",
    ]
    assert run_cli(argv, capsys)[0] == 0
    before = sorted(p.name for p in folder.iterdir())
    with unwritable(folder):
        with pytest.raises(PermissionError):
            (folder / "probe").touch()  # the folder really is read-only
        code, out, err = run_cli(["history", "--db", str(db), "--gearbox", "g", "--json"], capsys)
        assert code == 0, err
        assert '"estimates"' in out or '"backlash_deg"' in out
        code, out, err = run_cli(["history", "--db", str(db), "--gearbox", "g", "--check"], capsys)
        assert out.startswith("BACKLASH ") and "error" not in out, (
            out
        )  # a state, not an UNKNOWN for a store it cannot open
        code, _, err = run_cli(argv, capsys)  # writing still fails, with one line
        assert code == 1 and err.startswith("error: ") and "Traceback" not in err
    assert sorted(p.name for p in folder.iterdir()) == before


def test_console_script_never_shows_a_traceback(files):
    """The installed entry point, as a user runs it (a subprocess: the real stderr and exit code)."""
    exe = shutil.which("online-backlash") or str(Path(sys.executable).with_name("online-backlash"))
    done = subprocess.run(
        [exe, "estimate", str(files / "trunc.csv.gz"), "--ratio", "30"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 1 and "Traceback" not in done.stderr
    assert re.fullmatch(
        rf"error: {re.escape(str(files))}/trunc.csv.gz:\d+: damaged or truncated file: .*\n", done.stderr
    )
    debug = subprocess.run(
        [exe, "estimate", str(files / "trunc.csv.gz"), "--ratio", "30", "--debug"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert debug.returncode == 1 and "Traceback" in debug.stderr  # --debug after the subcommand shows it


def test_run_command_turns_every_failure_and_warning_into_one_line(capsys):
    def warns(_args: argparse.Namespace) -> int:
        warnings.warn("overflow\n  encountered", RuntimeWarning, stacklevel=1)
        warnings.warn("10 samples repeat", BacklashWarning, stacklevel=1)
        return 0

    def fails(_args: argparse.Namespace) -> int:
        raise KeyError("motor")

    with warnings.catch_warnings():
        warnings.simplefilter("default")  # as for a user; pytest's filter turns warnings into errors
        assert run_command(warns, argparse.Namespace()) == 0
    assert capsys.readouterr().err == "warning: RuntimeWarning: overflow encountered\nwarning: 10 samples repeat\n"
    assert run_command(fails, argparse.Namespace(debug=False)) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: unexpected KeyError: 'motor' (run with --debug") and err.count("\n") == 1
    with pytest.raises(KeyError):
        run_command(fails, argparse.Namespace(debug=True))

    def no_dbc(_args: argparse.Namespace) -> int:
        raise FileNotFoundError(2, "No such file or directory", "rig.dbc")

    assert run_command(no_dbc, argparse.Namespace()) == 1
    assert capsys.readouterr().err == "error: rig.dbc: no such file or folder\n"


def test_a_warning_of_another_thread_during_the_warm_start_reaches_the_user(monkeypatch):
    """The warm start records the batch fit's ConvergenceWarning with ``catch_warnings``, which takes every thread's
    warnings meanwhile: the read-ahead reader's (duplicated timestamps) was lost in 3 of 30 runs of ``estimate``."""
    from online_backlash.estimators.backlash_rls import BacklashRLS

    warm_fit = BacklashRLS._warm_fit

    def with_a_reader_warning(self, *args):
        reader = threading.Thread(target=warnings.warn, args=("10 samples repeat (from the reader)", BacklashWarning))
        reader.start()
        reader.join()
        return warm_fit(self, *args)

    monkeypatch.setattr(BacklashRLS, "_warm_fit", with_a_reader_warning)
    rec = simulate_rig(duration_s=5.0, ratio=30.0, play_deg=0.5, seed=4)
    with pytest.warns(BacklashWarning, match=r"from the reader"):
        BacklashRLS(warm_start_samples=2000).learn_many(rec.motor_deg / 30.0, rec.load_deg)
