"""Each option is declared once (issue 29 item 1): the CLI gives a flag one type, one set of choices and one
behaviour in every command; the help of a log argument is the registry's; the CAN and serial readers and the live
sources take the shared option dataclasses instead of restating their fields as keyword arguments."""

from __future__ import annotations

import dataclasses
import inspect

import numpy as np
import pytest
from test_formats import _options_of

from online_backlash.cli import build_parser, main
from online_backlash.codecs.dbc import RIG_DBC
from online_backlash.codecs.options import CanDecoding, Canopen, Counts, FrameRules, gather_options
from online_backlash.drivers.can import CanSource
from online_backlash.drivers.canopen import CanopenSource
from online_backlash.drivers.live import LiveOptions
from online_backlash.drivers.serial import SerialSource
from online_backlash.replay import open_log, registry
from online_backlash.replay.canlog import CanLog
from online_backlash.replay.canopenlog import CanopenLog
from online_backlash.replay.formats import LogFormat
from online_backlash.replay.serialcapture import SerialCapture
from online_backlash.simulation.rig_logs import write_rig_can_log, write_rig_serial_capture

#: Flags that name different things in different commands (``serve --port`` is a TCP port, ``listen serial
#: --port`` a pyserial URL; ``--every`` is the interval of trace rows, of stored or of published estimates; the
#: alarm levels are stored, published or forecast against; ``--plot`` draws a different figure in each command).
DIFFERENT_MEANINGS = {"--port", "--every", "--warn-arcmin", "--limit-arcmin", "--plot", "--json", "--gearbox", "--help"}


def test_every_option_has_one_type_and_one_set_of_choices_in_every_command():
    """--period was a positive float for estimate and any float for listen and track; --units a choice for the logs
    and free text for listen can; --memory-reversals and --sample-period positive for estimate only."""
    declared: dict[str, set[object]] = {}
    for where, action in _options_of(build_parser()):
        flag = where.split()[-1]
        if flag not in DIFFERENT_MEANINGS:
            choices = None if action.choices is None else tuple(action.choices)
            declared.setdefault(flag, set()).add((action.type, choices, action.dest))
    several = {flag: kinds for flag, kinds in declared.items() if len(kinds) > 1}
    assert not several
    assert {"--period", "--units", "--memory-reversals", "--sample-period", "--serial-format"} <= set(declared)


@pytest.mark.parametrize(
    "argv",
    [
        ["estimate", "run.csv", "--ratio", "30"],
        ["track", "run.csv", "--ratio", "30", "--db", "x.db", "--gearbox", "g"],
        ["listen", "serial", "--port", "loop://", "--format", "ascii", "--ratio", "30", "--raw-log", "raw"],
        ["listen", "can", "--interface", "virtual", "--channel", "c", "--ratio", "30", "--raw-log", "raw"],
    ],
    ids=["estimate", "track", "listen-serial", "listen-can"],
)
def test_a_bad_period_is_a_usage_error_in_every_command(argv, capsys, tmp_path, monkeypatch):
    """One declaration, one behaviour: argparse refuses the value before any work (exit 2, as every option's bad
    value), where listen and track took -1 and failed later (exit 1)."""
    monkeypatch.chdir(tmp_path)  # the old parser took -1, and track went on to make its store
    with pytest.raises(SystemExit) as stop:
        main([*argv, "--period", "-1"])
    assert stop.value.code == 2
    assert "--period: expected a positive number, got '-1'" in capsys.readouterr().err


def test_listen_can_takes_the_units_of_the_logs(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["listen", "can", "--interface", "virtual", "--channel", "c", "--ratio", "30", "--raw-log", "r",
              "--units", "furlongs"])  # fmt: skip
    assert stop.value.code == 2
    assert "--units: invalid choice: 'furlongs'" in capsys.readouterr().err


def test_the_help_of_a_log_argument_lists_the_registry(monkeypatch, capsys):
    monkeypatch.setattr(registry, "FORMATS", list(registry.FORMATS))
    monkeypatch.setattr(registry, "LOG_READERS", dict(registry.LOG_READERS))
    registry.register_format(LogFormat("toy", (".toy",), CanLog, title="toy logs, with nothing"))
    for command in ("estimate", "diagnose", "track"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert ".toy (toy logs, with nothing)" in " ".join(capsys.readouterr().out.split()), command
    with pytest.raises(SystemExit):
        main(["inspect", "--help"])
    assert ".toy" not in capsys.readouterr().out  # inspect lists the formats it can describe


SHARED = (CanDecoding, Canopen, Counts, FrameRules, LiveOptions)
READERS_AND_SOURCES = (CanLog, CanopenLog, SerialCapture, CanSource, CanopenSource, SerialSource)


@pytest.mark.parametrize("cls", READERS_AND_SOURCES, ids=lambda c: c.__name__)
def test_no_reader_or_live_source_restates_a_field_of_a_shared_option(cls):
    fields = {f.name for option in SHARED for f in dataclasses.fields(option)} - {"serial_format"}
    parameters = set(inspect.signature(cls).parameters)
    assert not parameters & fields, parameters & fields


def test_open_logs_keywords_are_gathered_into_the_options(tmp_path):
    """``open_log``'s flat keywords (every format's) make the same reader as the option objects."""
    path = tmp_path / "run.blf"
    write_rig_can_log(path, duration_s=2.0, seed=1)
    flat = {"dbc": RIG_DBC, "motor_signal": "MotorAngle.Count", "load_signal": "LoadAngle.Count", "period_s": 1e-3}
    gathered = gather_options({**flat, "skip_bad": True}, decoding=CanDecoding, frames=FrameRules, counts=Counts)
    assert gathered == {
        "decoding": CanDecoding(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count"),
        "frames": FrameRules(period_s=1e-3),
        "counts": Counts(),
        "skip_bad": True,
    }
    by_keywords = open_log(path, **flat)
    by_objects = CanLog(path, CanDecoding(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count"), frames=FrameRules(1e-3))
    a, b = (np.concatenate([c.time_s for c in log.iter_chunks()]) for log in (by_keywords, by_objects))
    assert a.size > 1000 and np.array_equal(a, b)
    assert by_keywords.counters.as_dict() == by_objects.counters.as_dict()
    with pytest.raises(TypeError, match="unexpected keyword argument 'motor_cpr_typo'"):
        open_log(path, **flat, motor_cpr_typo=1)


def test_a_serial_capture_reads_alike_by_keywords_and_by_options(tmp_path):
    path = tmp_path / "run.serial"
    write_rig_serial_capture(path, "binary", duration_s=1.0, motor_cpr=2**14, load_cpr=2**17, seed=1)
    by_keywords = open_log(path, serial_format="binary", motor_cpr=2**14, load_cpr=2**17)
    by_objects = SerialCapture(path, "binary", counts=Counts(2**14, 2**17))
    a, b = (np.concatenate([c.load_deg for c in log.iter_chunks()]) for log in (by_keywords, by_objects))
    assert a.size == 1000 and np.array_equal(a, b)
