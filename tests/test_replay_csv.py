"""CSV logs: column mapping, units, bad rows named by file and line, skipping, gaps, real data."""

from __future__ import annotations

import codecs
import csv
import gzip
import io
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from davinci_runs import DAVINCI, READ
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from online_backlash.codecs.gaps import GapDetector
from online_backlash.errors import BacklashWarning, InvalidParameterError, LogFormatError
from online_backlash.replay import CsvLog, open_log, read_csv_arrays, read_log_arrays
from online_backlash.replay.csv import CsvDialect, sniff_dialect
from online_backlash.stream import Sample


def write(tmp_path: Path, text: str, name: str = "log.csv") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_reads_default_columns_in_degrees(tmp_path):
    path = write(tmp_path, "time,motor,load,extra\n0.0,1.5,2.5,x\n0.001,1.6,2.6,y\n")
    with CsvLog(path) as log:
        samples = list(log)
    assert samples == [Sample(0.0, 1.5, 2.5), Sample(0.001, 1.6, 2.6)]
    assert log.counters.as_dict() == {"frames": 2, "samples": 2, "corrupt": 0, "skipped": 0, "gaps": 0}


def test_column_map_units_and_torque(tmp_path):
    path = write(tmp_path, "t_s,m,l,tq\n0,4096,8192,0.5\n0.001,-2048,0,-0.25\n")
    opts = {
        "columns": {"time": "t_s", "motor": "m", "load": "l", "torque": "tq"},
        "units": "counts",
        "motor_cpr": 4096,
        "load_cpr": 8192,
    }
    samples = list(CsvLog(path, **opts))
    assert samples[0] == Sample(0.0, 360.0, 360.0, 0.5)
    assert samples[1] == Sample(0.001, -180.0, 0.0, -0.25)
    rad = list(CsvLog(write(tmp_path, "time,motor,load\n0,3.141592653589793,0\n", "r.csv"), units="rad"))
    assert rad[0].motor_deg == pytest.approx(180.0)


def test_gzip_is_read_transparently(tmp_path):
    path = tmp_path / "log.csv.gz"
    with gzip.open(path, "wt") as f:
        f.write("time,motor,load\n0,1,2\n0.001,1,2\n")
    assert len(list(open_log(path))) == 2


@pytest.mark.parametrize(
    "row, reason",
    [
        ("0.002,1.0\n", "expected 3 columns, got 2"),
        ("0.002,abc,1.0\n", "not a number"),
        ("0.002,nan,1.0\n", "non-finite value"),
        ("0.002,1.0,inf\n", "non-finite value"),
        ("0.0005,1.0,1.0\n", "time goes backwards"),
    ],
)
def test_bad_row_names_file_and_line(tmp_path, row, reason):
    path = write(tmp_path, "time,motor,load\n0,0,0\n0.001,0,0\n" + row + "0.003,0,0\n")
    with pytest.raises(LogFormatError) as info:
        list(CsvLog(path))
    assert str(info.value).startswith(f"{path}:4: ")
    assert reason in str(info.value)
    assert info.value.line == 4


def test_skip_bad_rows_counts_and_never_yields_them(tmp_path):
    path = write(tmp_path, "time,motor,load\n0,0,0\n0.001,nan,0\n0.002,1\n0.0015,0,0\n0.001,0,0\n0.003,1,1\n")
    log = CsvLog(path, skip_bad=True)
    samples = list(log)
    assert [s.time_s for s in samples] == [0.0, 0.0015, 0.003]
    c = log.counters
    assert (c.frames, c.samples, c.corrupt) == (6, 3, 3)
    assert c.frames == c.samples + c.corrupt


def test_gap_is_reported_and_marks_next_sample(tmp_path):
    rows = [f"{i * 0.001:.3f},{i},{i}" for i in range(30)] + [f"{0.07 + i * 0.001:.3f},{i},{i}" for i in range(5)]
    path = write(tmp_path, "time,motor,load\n" + "\n".join(rows) + "\n")
    log = CsvLog(path)
    samples = list(log)
    assert [s.after_gap for s in samples].index(True) == 30
    assert log.counters.gaps == 1 and log.nominal_period_s == pytest.approx(0.001)
    gap = log.counters.gap_log[0]
    assert gap.time_s == pytest.approx(0.07)
    assert gap.duration_s == pytest.approx(0.041)
    assert gap.missing == 40


def test_the_gap_rule_is_the_frame_sources_rule(tmp_path):
    """The period is learnt from the first steps as for CAN and serial frames (a gap before it is
    known goes unseen), or given; the gaps are those of GapDetector.check, block size aside."""
    rows = (
        [f"{i * 0.001:.3f},{i},{i}" for i in range(10)]
        + [f"{0.05 + i * 0.001:.3f},{i},{i}" for i in range(40)]
        + ["0.5,0,0", "0.5004,0,0"]
    )
    path = write(tmp_path, "time,motor,load\n" + "\n".join(rows) + "\n")
    times = [float(r.split(",")[0]) for r in rows]
    detector = GapDetector()
    expected = [detector.check(t) for t in times]
    for block_rows in (3, 65536):
        log = CsvLog(path, block_rows=block_rows)
        assert [s.after_gap for s in log] == [g is not None for g in expected]
        assert list(log.counters.gap_log) == [g for g in expected if g is not None] and log.counters.gaps == 1
    given = CsvLog(path, period_s=0.001)
    assert [i for i, s in enumerate(given) if s.after_gap] == [10, 50]
    with pytest.raises(InvalidParameterError, match="period_s"):
        CsvLog(path, period_s=0.0)


def test_missing_header_column_and_unknown_role(tmp_path):
    with pytest.raises(LogFormatError, match=r"log.csv:1: header has no column \['motor'\]"):
        list(CsvLog(write(tmp_path, "time,mot,load\n0,0,0\n")))
    with pytest.raises(InvalidParameterError, match="unknown column roles"):
        CsvLog("x.csv", columns={"speed": "v"})
    with pytest.raises(InvalidParameterError, match="motor_cpr"):
        CsvLog("x.csv", units="counts", load_cpr=10)
    with pytest.raises(LogFormatError, match=r"unknown log format '\.bin'"):
        open_log("x.bin")


def test_chunks_equal_rows_across_block_boundaries(tmp_path):
    rng = np.random.default_rng(0)
    data = np.column_stack((np.arange(1000) * 0.001, rng.normal(size=1000), rng.normal(size=1000)))
    path = tmp_path / "log.csv"
    np.savetxt(path, data, delimiter=",", header="time,motor,load", comments="", fmt="%.17g")
    small = read_csv_arrays(path, block_rows=7)
    big = read_csv_arrays(path)
    np.testing.assert_array_equal(small.motor_deg, data[:, 1])
    np.testing.assert_array_equal(big.load_deg, small.load_deg)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(body=st.text(alphabet="0123456789.,-eEnaif \n", max_size=300))
def test_fuzzed_rows_raise_only_log_format_error_and_counters_reconcile(tmp_path, body):
    path = write(tmp_path, "time,motor,load\n" + body)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BacklashWarning)  # repeated times are counted in a warning
        try:
            samples = list(CsvLog(path))
        except LogFormatError as exc:
            assert exc.path == str(path) and exc.line is not None and exc.line >= 2
        else:
            assert all(s.is_finite() for s in samples)
        log = CsvLog(path, skip_bad=True, block_rows=4)
        try:
            samples = list(log)
        except LogFormatError as exc:  # a file-level fault no row skipping can mend
            assert "never advances" in exc.reason and exc.line is not None
            return
    assert all(math.isfinite(s.motor_deg) and math.isfinite(s.load_deg) for s in samples)
    assert log.counters.frames == log.counters.samples + log.counters.corrupt
    times = [s.time_s for s in samples]
    assert times == sorted(times)


# -- CSV as people write it ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def frame():
    """A table with awkward values (negative, tiny, large, many digits) and a torque column."""
    import pandas as pd

    rng = np.random.default_rng(3)
    n = 700  # the sniffer sees only the first few KB; the rest is read by pandas in blocks
    return pd.DataFrame(
        {
            "time": np.arange(n) * 0.001,
            "motor": rng.normal(0, 5000, n),
            "load": rng.normal(0, 100, n) * 1e-3,
            "torque": rng.normal(0, 2, n),
        }
    )


def _excel_writer(quoting: int, encoding: str) -> object:
    def write_file(df: object, path: Path) -> None:
        with open(path, "w", newline="", encoding=encoding) as f:
            writer = csv.writer(f, dialect="excel", quoting=quoting)  # excel: CRLF line ends
            writer.writerow(df.columns)
            writer.writerows(df.itertuples(index=False))

    return write_file


WRITERS = {
    # German Excel / pandas: ';' separator, decimal comma
    "pandas-sep;-decimal,": (lambda df, path: df.to_csv(path, sep=";", decimal=",", index=False), CsvDialect(";", ",")),
    "pandas-tab": (lambda df, path: df.to_csv(path, sep="\t", index=False), CsvDialect("\t", ".")),
    "pandas-pipe-gz": (
        lambda df, path: df.to_csv(path, sep="|", index=False, compression="gzip"),
        CsvDialect("|", "."),
    ),
    "csv-excel-crlf-bom": (_excel_writer(csv.QUOTE_MINIMAL, "utf-8-sig"), CsvDialect(",", ".")),
    "csv-quote-all-bom": (_excel_writer(csv.QUOTE_ALL, "utf-8-sig"), CsvDialect(",", ".")),
    "csv-quote-all-crlf": (_excel_writer(csv.QUOTE_ALL, "utf-8"), CsvDialect(",", ".")),
    "pandas-quote-all-sep;-decimal,": (
        lambda df, path: df.to_csv(path, sep=";", decimal=",", index=False, quoting=csv.QUOTE_ALL),
        CsvDialect(";", ","),
    ),
}


@pytest.mark.parametrize("writer", WRITERS)
@pytest.mark.parametrize("block_rows", [65536, 64])
def test_dialects_written_by_the_tools_people_use_read_the_same_samples(tmp_path, frame, writer, block_rows):
    write_file, dialect = WRITERS[writer]
    path = tmp_path / ("log.csv.gz" if writer.endswith("-gz") else "log.csv")
    write_file(frame, path)
    log = CsvLog(path, block_rows=block_rows)
    chunk = read_csv_arrays(path, block_rows=block_rows)
    with log:
        list(log.iter_chunks())
    assert log.dialect == dialect
    # the text round trip of pandas/csv keeps every digit of a float64
    np.testing.assert_array_equal(chunk.time_s, frame["time"].to_numpy())
    np.testing.assert_array_equal(chunk.motor_deg, frame["motor"].to_numpy())
    np.testing.assert_array_equal(chunk.load_deg, frame["load"].to_numpy())
    np.testing.assert_array_equal(chunk.torque_Nm, frame["torque"].to_numpy())
    assert log.counters.as_dict()["frames"] == len(frame) and log.counters.corrupt == 0


def test_a_bad_row_of_a_german_excel_file_is_named_by_its_line(tmp_path, frame):
    path = tmp_path / "de.csv"
    frame.to_csv(path, sep=";", decimal=",", index=False)
    lines = path.read_text().splitlines(keepends=True)
    lines[301] = "0,3;zwölf;1,0;0\n"  # line 302 of the file
    path.write_text("".join(lines))
    with pytest.raises(LogFormatError) as info:
        read_csv_arrays(path, block_rows=100)
    assert info.value.line == 302 and "not a number" in info.value.reason
    log = CsvLog(path, skip_bad=True)
    assert sum(len(c) for c in log.iter_chunks()) == len(frame) - 1 and log.counters.corrupt == 1


def test_delimiter_and_decimal_override_the_guess(tmp_path):
    # integers only in the first KB the sniffer reads: nothing there tells the decimal comma
    rows = [f"{i};{i};{i}" for i in range(2000)] + ["2000;5,5;5,25"]
    path = write(tmp_path, "time;motor;load\n" + "\n".join(rows) + "\n")
    with pytest.raises(LogFormatError, match=r":2002: not a number"):
        read_csv_arrays(path)
    chunk = read_csv_arrays(path, decimal=",")
    assert chunk.motor_deg[-1] == 5.5 and chunk.load_deg[-1] == 5.25
    forced = write(tmp_path, "time,motor,load\n0,1,2\n", "forced.csv")
    with pytest.raises(LogFormatError, match=r"forced.csv:1: header has no column"):
        read_csv_arrays(forced, delimiter=";")
    for bad in ({"delimiter": "ab"}, {"delimiter": "1"}, {"decimal": ";"}, {"delimiter": ",", "decimal": ","}):
        with pytest.raises(InvalidParameterError):
            CsvLog(path, **bad)


@pytest.mark.parametrize(
    "sample, expected",
    [
        ("time;motor;load\n0,001;1,5;2,5\n", CsvDialect(";", ",")),
        ("time;motor;load\n0.001;1.5;2.5\n", CsvDialect(";", ".")),
        ("time\tmotor\tload\r\n0.1\t1\t2\r\n", CsvDialect("\t", ".")),
        ('"time","motor","load"\r\n"0.1","1","2"\r\n', CsvDialect(",", ".")),
        ("time|motor|load\n", CsvDialect("|", ".")),  # a header alone: the header decides
        ("t\n1\n", CsvDialect(",", ".")),  # one column: the default
    ],
)
def test_sniffed_dialect(sample, expected):
    assert sniff_dialect(sample) == expected


def test_truncated_gzip_names_the_line_where_it_ends(tmp_path):
    text = "time,motor,load\n" + "".join(f"{i * 0.001:.3f},{i % 7},{i % 5}\n" for i in range(20000))
    data = gzip.compress(text.encode())
    path = tmp_path / "cut.csv.gz"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(LogFormatError) as info:
        read_csv_arrays(path, block_rows=1000)
    assert info.value.line is not None and 2 < info.value.line < 20002 and "truncated" in info.value.reason
    fake = tmp_path / "fake.csv.gz"
    fake.write_text(text[:200])
    with pytest.raises(LogFormatError, match=r"fake.csv.gz:1: damaged or truncated"):
        read_csv_arrays(fake)


def test_a_byte_that_is_not_utf8_is_named_by_its_line(tmp_path):
    rows = "".join(f"{i * 0.001:.3f},{i % 9},{i % 4}\n" for i in range(2000))
    path = tmp_path / "latin1.csv"
    path.write_bytes(b"time,motor,load\n" + rows.encode() + "0.5,1,2 \u00b0\n".encode("latin-1") + b"0.6,1,2\n")
    with pytest.raises(LogFormatError, match=r"latin1.csv:2002: not a text CSV file: not UTF-8"):
        read_csv_arrays(path, block_rows=500)
    binary = tmp_path / "binary.csv"
    binary.write_bytes(bytes(range(128, 256)) * 40)
    with pytest.raises(LogFormatError, match=r"binary.csv:1: not a text CSV file"):
        read_csv_arrays(binary)


def test_time_that_never_advances_is_an_error_and_repeated_times_are_counted(tmp_path):
    rows = "".join(f"0,{i},{i}\n" for i in range(50))
    with pytest.raises(LogFormatError, match=r"zeros.csv:51: time column 'time' never advances: all 50 samples at 0 s"):
        read_csv_arrays(write(tmp_path, "time,motor,load\n" + rows, "zeros.csv"))
    times = [0.0, 0.001, 0.001, 0.002, 0.003, 0.003, 0.004]  # one repeat inside a block of 3, one across blocks
    path = write(tmp_path, "time,motor,load\n" + "".join(f"{t},{i},{i}\n" for i, t in enumerate(times)), "dups.csv")
    with pytest.warns(BacklashWarning, match=r"dups.csv: 2 of 7 samples repeat the previous sample's time"):
        chunk = read_csv_arrays(path, block_rows=3)
    assert list(chunk.time_s) == times
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_csv_arrays(write(tmp_path, "time,motor,load\n0,0,0\n0.001,1,1\n", "clean.csv"))  # no warning


def test_angles_beyond_float64_resolution_are_refused_by_line(tmp_path):
    rows = "time,motor,load\n0,0,0\n0.001,1e300,1\n0.002,1,-2e16\n0.003,1,1\n"
    with pytest.raises(LogFormatError, match=r"huge.csv:3: angle beyond 1e\+15 deg"):
        read_csv_arrays(write(tmp_path, rows, "huge.csv"))
    log = CsvLog(tmp_path / "huge.csv", skip_bad=True)
    assert sum(len(c) for c in log.iter_chunks()) == 2 and log.counters.corrupt == 2
    # counts under a degrees header are big but resolvable: accepted (the plausibility check names them)
    assert len(read_csv_arrays(write(tmp_path, "time,motor,load\n0,4e9,1e6\n0.001,4e9,1e6\n", "counts.csv"))) == 2


RECORDINGS = [
    "tool4_L_run00_0.1Hz_torque10pct.csv",
    "tool4_L_run20_0.3Hz_torque10pct.csv",
    "tool4_L_run49_0.5Hz_torque100pct.csv",
]


@pytest.mark.parametrize("name", RECORDINGS)
def test_measured_recordings_load_and_fit_sensibly(name):
    from online_backlash import VorosBacklash

    chunk = read_csv_arrays(DAVINCI / name, **{**READ, "columns": {**READ["columns"], "torque": "backend_torque_Nm"}})
    assert len(chunk) > 19_000 and not chunk.after_gap.any()
    est = VorosBacklash(origin="first").fit(
        chunk.motor_deg / -35.0, chunk.load_deg
    )  # encoder zeros are arbitrary, as in the CLI
    # the data README measures 1.6-1.7 deg of total lost motion (gearhead, output side)
    assert 1.4 < est.backlash_ < 2.0
    assert 0.97 < est.m_left_ < 1.03 and 0.97 < est.m_right_ < 1.03


def _excel_rows(frame) -> list[list[str]]:
    return [list(frame.columns)] + [[repr(v) for v in row] for row in frame.itertuples(index=False)]


def _comment_preamble(path: Path, frame) -> dict:
    with open(path, "w", newline="") as f:
        f.write("# logger v2.1\n# rig 7, channel map below\n")
        csv.writer(f).writerows(_excel_rows(frame))
    return {}


def _windows_semicolon(path: Path, frame) -> dict:
    """A Windows export: cp1252, ``;``, decimal comma, a degree sign in the header."""
    with open(path, "w", encoding="cp1252", newline="") as f:
        writer = csv.writer(f, delimiter=";")
        writer.writerow(["time [s]", "motor [°]", "load [°]"])
        writer.writerows([[repr(v).replace(".", ",") for v in row] for row in frame.itertuples(index=False)])
    return {"encoding": "cp1252", "columns": {"time": "time [s]", "motor": "motor [°]", "load": "load [°]"}}


def _excel_unicode_text(path: Path, frame, codec: str = "utf-16") -> dict:
    """Excel's "Unicode text": UTF-16 with a byte-order mark, tab separated, CRLF (``codecs`` writes the mark)."""
    with codecs.open(str(path), "w", encoding=codec) as f:
        if codec != "utf-16":  # utf-16 writes its own mark; the explicit-endian codecs do not
            f.write("\ufeff")
        csv.writer(f, delimiter="\t", lineterminator="\r\n").writerows(_excel_rows(frame))
    return {}


@pytest.mark.parametrize(
    "name, writer",
    [
        ("commented.csv", _comment_preamble),
        ("windows.csv", _windows_semicolon),
        ("unicode.txt", _excel_unicode_text),
        ("unicode_be.txt", lambda p, f: _excel_unicode_text(p, f, "utf-16-be")),
        ("utf8_bom.tsv", lambda p, f: _excel_unicode_text(p, f, "utf-8")),
    ],
)
def test_files_people_have_read_the_same_samples(tmp_path, name, writer):
    import pandas as pd

    frame = pd.DataFrame(
        {"time": np.arange(50) * 1e-3, "motor": np.sin(np.arange(50) / 7.0) * 30, "load": np.cos(np.arange(50) / 9.0)}
    )
    options = writer(tmp_path / name, frame)
    chunk = read_log_arrays(tmp_path / name, **options)
    assert np.array_equal(chunk.time_s, frame["time"]) and np.array_equal(chunk.motor_deg, frame["motor"])
    assert np.array_equal(chunk.load_deg, frame["load"])


def test_a_comment_character_skips_its_lines_anywhere_and_lines_keep_their_numbers(tmp_path):
    path = write(
        tmp_path,
        "% exported 2026-11-22\ntime,motor,load\n0,1,2\n% pause\n0.001,1,2\n  % resumed\n0.002,x,2\n",
        "pct.csv",
    )
    with pytest.raises(LogFormatError, match=r"pct.csv:7: not a number"):
        read_csv_arrays(path, comment="%")
    with pytest.raises(LogFormatError, match=r"pct.csv:1: header has no column"):
        read_csv_arrays(path)  # '%' is not sniffed: only '#'
    path.write_text(path.read_text().replace("0.002,x,2", "0.002,1,2"))
    assert read_csv_arrays(path, comment="%").time_s.tolist() == [0.0, 0.001, 0.002]
    with pytest.raises(InvalidParameterError, match="comment must be one character"):
        CsvLog(path, comment="1")


def test_a_byte_not_in_utf8_names_the_encoding_option(tmp_path):
    path = tmp_path / "win.csv"
    path.write_bytes("time;motor [°];load\n0;1;2\n".encode("cp1252"))
    with pytest.raises(LogFormatError, match=r"win.csv:1: not a text CSV file: not UTF-8 \(byte 0xB0.*--encoding"):
        read_csv_arrays(path, columns={"motor": "motor [°]"})
    with pytest.raises(InvalidParameterError, match="unknown text encoding 'klingon'"):
        CsvLog(path, encoding="klingon")


def test_nul_bytes_are_refused_from_the_first_block_however_large_the_file(tmp_path):
    """A 2 GiB sparse file of NUL bytes (no disk used): refused from its first 4 KB, not read to its end
    (before: "field larger than field limit" after 18 s)."""
    path = tmp_path / "zeros.csv"
    with open(path, "wb") as f:
        f.truncate(2 << 30)
    with pytest.raises(
        LogFormatError, match=r"zeros.csv:1: not a text CSV file: NUL bytes in its first 4096 bytes \(binary data"
    ):
        read_csv_arrays(path)


def test_blocks_reach_the_parser_as_utf8_bytes(tmp_path, monkeypatch):
    """A block of rows goes to pandas' C parser as UTF-8 bytes, not a ``StringIO`` (which holds 4 bytes a
    character and is encoded by pandas again: 13.6 against 5.8 MB at the parse's peak for 65,536 rows; issue 31),
    and reads the same samples, a cp1252 file with a degree sign in its header too."""
    import pandas as pd

    given = []
    read_csv = pd.read_csv

    def spy(source, *args, **kwargs):
        given.append(type(source))
        return read_csv(source, *args, **kwargs)

    monkeypatch.setattr(pd, "read_csv", spy)
    path = tmp_path / "export.csv"
    path.write_bytes("time;motor \xb0;load \xb0\n0,001;1,5;2,5\n0,002;1,75;2,25\n".encode("cp1252"))
    columns = {"motor": "motor \xb0", "load": "load \xb0"}
    chunk = read_csv_arrays(path, columns=columns, encoding="cp1252")
    assert given and set(given) == {io.BytesIO}
    np.testing.assert_array_equal(chunk.motor_deg, [1.5, 1.75])
    np.testing.assert_array_equal(chunk.load_deg, [2.5, 2.25])


def test_a_block_is_parsed_in_pieces_and_handed_on_whole(tmp_path, monkeypatch):
    """The lines of a block go to the parser ``PARSE_ROWS`` at a time (one Python string a line is what a parse
    holds most of; issue 31), and the blocks handed on stay ``block_rows`` long, so the estimators see the same
    blocks; a bad line in the second piece is still named by its own line."""
    import pandas as pd

    import online_backlash.replay.csv as csv_reader

    monkeypatch.setattr(csv_reader, "PARSE_ROWS", 4)
    rows = []
    read_csv = pd.read_csv

    def spy(source, *args, **kwargs):
        rows.append(source.getvalue().count(b"\n"))
        return read_csv(source, *args, **kwargs)

    monkeypatch.setattr(pd, "read_csv", spy)
    path = tmp_path / "rows.csv"
    path.write_text("time,motor,load\n" + "".join(f"{i * 1e-3},{i},{-i}\n" for i in range(25)))
    with CsvLog(path, block_rows=10) as log:
        chunks = list(log.iter_chunks())
    assert [len(c) for c in chunks] == [10, 10, 5]
    assert max(rows) == 4
    np.testing.assert_array_equal(np.concatenate([c.motor_deg for c in chunks]), np.arange(25))
    lines = path.read_text().splitlines()
    lines[16] = "0.015,x,-15"  # line 17 of the file: the second piece of the second block
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(LogFormatError, match=r":17: not a number"):
        read_csv_arrays(path, block_rows=10)
