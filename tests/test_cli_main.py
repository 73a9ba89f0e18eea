"""The CLI frame and the demo: subcommands are discovered, errors are one line, demo runs offline."""

from __future__ import annotations

import re

import pytest

from online_backlash.cli import build_parser, main


def test_every_subcommand_has_help(capsys):
    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices  # argparse keeps them here
    assert {"demo", "estimate"} <= set(commands)
    for name in commands:
        with pytest.raises(SystemExit) as info:
            main([name, "--help"])
        assert info.value.code == 0
        assert name in capsys.readouterr().out


def test_error_is_one_line_and_exit_code_1(tmp_path, capsys):
    missing = tmp_path / "nope.csv"
    assert main(["estimate", str(missing), "--ratio", "30"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and str(missing) in err


def test_bad_row_error_names_file_and_line(tmp_path, capsys):
    log = tmp_path / "bad.csv"
    log.write_text("time,motor,load\n0,0,0\n0.001,1,x\n")
    assert main(["estimate", str(log), "--ratio", "30", "--method", "batch"]) == 1
    assert f"error: {log}:3: not a number" in capsys.readouterr().err


def test_demo_reports_the_bundled_play_and_writes_a_plot(tmp_path, capsys):
    plot = tmp_path / "demo.png"
    assert main(["demo", "--plot", str(plot)]) == 0
    out = capsys.readouterr().out
    backlash = float(re.search(r"backlash:\s+([0-9.]+) deg", out).group(1))
    assert backlash == pytest.approx(0.5, rel=0.02)  # the recording was made with 0.50 deg of play
    assert plot.stat().st_size > 10_000 and plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
