"""A format is declared once (issue 29 item 1): one LogFormat and one registry line make a new format readable by
``estimate`` and ``inspect``, its options taken from the CLI's arguments by type; a suffix two formats share goes
by content."""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Iterator

import numpy as np
import pytest

from online_backlash.cli import build_parser, main
from online_backlash.errors import InvalidParameterError
from online_backlash.replay import registry
from online_backlash.replay.formats import LogFormat
from online_backlash.replay.options import Timing, Units
from online_backlash.replay.summary import ChannelInfo, FileSummary
from online_backlash.simulation.rig import simulate_rig
from online_backlash.stream import SampleChunk, SampleSource, StreamCounters


class ToyLog(SampleSource):
    """A toy format: lines ``time motor load`` separated by spaces (seconds, angles in ``units``)."""

    def __init__(self, path: str | os.PathLike[str], units: str | None = None) -> None:
        self.values = np.loadtxt(path, ndmin=2)
        self.scale = np.degrees(1.0) if units == "rad" else 1.0
        self.counters = StreamCounters()

    def iter_chunks(self, max_samples: int | None = None) -> Iterator[SampleChunk]:
        time_s, motor, load = self.values.T
        self.counters.frames = self.counters.samples = len(time_s)
        n = len(time_s)
        yield SampleChunk(time_s, motor * self.scale, load * self.scale, np.full(n, np.nan), np.zeros(n, bool))

    def close(self) -> None:
        pass


def describe_toy(path: str, **_: object) -> FileSummary:
    rows = len(np.loadtxt(path, ndmin=2))
    return FileSummary(path, "toy", [ChannelInfo(name, "float64", rows) for name in ("time", "motor", "load")])


TOY = LogFormat("toy", (".toy",), ToyLog, (Units,), describe_toy)


@pytest.fixture
def toy_log(tmp_path, monkeypatch):
    """A simulated rig (play 0.5 deg) written as a toy file in radians, the toy format registered for the test."""
    monkeypatch.setattr(registry, "FORMATS", list(registry.FORMATS))
    monkeypatch.setattr(registry, "LOG_READERS", dict(registry.LOG_READERS))
    rec = simulate_rig(duration_s=20.0, play_deg=0.5, seed=2)
    path = tmp_path / "run.toy"
    np.savetxt(path, np.column_stack([rec.time_s, np.radians(rec.motor_deg), np.radians(rec.load_deg)]))
    return str(path)


def test_a_format_is_one_object_and_one_registry_line(toy_log, capsys):
    assert main(["estimate", toy_log, "--ratio", "30", "--units", "rad", "--json"]) == 1
    assert "unknown log format '.toy'" in capsys.readouterr().err

    registry.register_format(TOY)

    assert main(["estimate", toy_log, "--ratio", "30", "--units", "rad", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["backlash_deg"] == pytest.approx(0.5, abs=0.02)
    assert report["samples"] == 20000
    main(
        ["estimate", toy_log, "--ratio", "30", "--json"]
    )  # --units reached the reader: without it, radians read as deg
    assert (json.loads(capsys.readouterr().out)["backlash_deg"] or 0.0) < 0.05
    assert main(["inspect", toy_log]) == 0
    assert capsys.readouterr().out.splitlines()[:3] == [
        f"{toy_log}: toy, 3 columns",
        "name   group  unit  type     samples  rate_hz",
        "time                float64  20000",
    ]


def test_options_a_format_does_not_take_are_refused():
    assert TOY.reader_kwargs([Units("rad")]) == {"units": "rad"}
    with pytest.raises(InvalidParameterError, match="toy log takes no Timing"):
        TOY.reader_kwargs([Timing(0.001)])


def test_a_shared_suffix_goes_by_content_and_a_recognising_format_comes_first(tmp_path, monkeypatch):
    monkeypatch.setattr(registry, "FORMATS", list(registry.FORMATS))
    monkeypatch.setattr(registry, "LOG_READERS", dict(registry.LOG_READERS))
    signals = LogFormat("signals", (".blf",), ToyLog, recognises=lambda path: str(path).endswith("signals.blf"))
    registry.register_format(signals)
    assert registry.FORMATS.index(signals) < registry.FORMATS.index(registry.CAN)
    assert registry.format_of(tmp_path / "signals.blf") is signals
    assert registry.format_of(tmp_path / "bus.blf") is registry.CAN
    assert registry.LOG_READERS[".blf"] is not ToyLog  # a shared suffix's reader decides by content


def _options_of(parser: argparse.ArgumentParser, path: str = "") -> Iterator[tuple[str, argparse.Action]]:
    """Every option of ``parser`` and of its subcommands (``path``: the subcommands' names)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _options_of(sub, f"{path} {name}".strip())
        else:
            yield from ((f"{path} {flag}", action) for flag in action.option_strings)


def test_every_option_a_reader_takes_is_declared_with_one_type():
    """--motor-cpr was int for listen can, float for listen serial, a positive float for the rest (issue 29)."""
    declared: dict[str, set[object]] = {}
    for where, action in _options_of(build_parser()):
        declared.setdefault(where.split()[-1], set()).add(action.type)
    for flag in (
        "--motor-cpr",
        "--load-cpr",
        "--columns",
        "--delimiter",
        "--encoding",
        "--dbc",
        "--max-skew",
        "--wrap-deg",
    ):
        assert len(declared[flag]) == 1, (flag, declared[flag])
