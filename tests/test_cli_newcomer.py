"""What a newcomer met in the first hour (issue 26, item 3): the help lists what a command reads, a command
that writes a file says where, and a figure printed and plotted is one figure, computed once."""

from __future__ import annotations

import json
import re

import pytest

from online_backlash.cli import main
from online_backlash.simulation.two_mass_rig import simulate_two_mass

#: Suffixes every log-reading command reads (one of each reader: CSV and delimited text, MDF, TDMS, Parquet, CAN,
#: serial).
READ_BY_EVERY_COMMAND = (".csv", ".txt", ".mf4", ".tdms", ".parquet", ".arrow", ".blf", ".serial")


@pytest.mark.parametrize("command", ["estimate", "diagnose", "track"])
def test_the_help_of_every_log_command_lists_the_formats_it_reads(command, capsys):
    with pytest.raises(SystemExit) as done:
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert done.value.code == 0
    assert [suffix for suffix in READ_BY_EVERY_COMMAND if suffix not in text] == []


@pytest.fixture(scope="module")
def loaded(tmp_path_factory):
    """A two-mass rig whose load torque reverses (the play observable), with its torque column."""
    path = tmp_path_factory.mktemp("newcomer") / "loaded.csv"
    simulate_two_mass(duration_s=6.0, play_deg=0.4, external_torque_nm=0.2, seed=6).write_csv(path)
    return path


def test_a_command_that_writes_a_file_says_where(capsys, loaded, tmp_path):
    plot, trace, report = tmp_path / "curve.png", tmp_path / "trace.csv", tmp_path / "report.md"
    assert main(["estimate", str(loaded), "--ratio", "30", "--plot", str(plot), "--trace", str(trace)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-2:] == [f"plot:           {plot}", f"trace:          {trace}"] and plot.is_file() and trace.is_file()
    assert main(["estimate", str(loaded), "--ratio", "30", "--plot", str(plot), "--json"]) == 0
    assert "plot" not in json.loads(capsys.readouterr().out)  # JSON stays the report: its reader gave the path
    assert (
        main(
            ["diagnose", str(loaded), "--ratio", "30", "--plot", str(plot), "--report", str(report), "--max-terms", "1"]
        )
        == 0
    )
    assert capsys.readouterr().out.splitlines()[-2:] == [f"plot:           {plot}", f"report:         {report}"]


@pytest.mark.parametrize("method", ["recursive", "batch"])
def test_the_lost_motion_printed_is_the_one_plotted(capsys, loaded, tmp_path, monkeypatch, method):
    """The README's torque example printed 126.703 arcmin and drew 125.66 (a recursive figure in the text, a batch
    fit's in the plot): the text now shows the figure of the curve drawn, computed once."""
    import online_backlash.plotting as plotting

    drawn = []
    monkeypatch.setattr(
        plotting, "plot_hysteresis", lambda curve, *args, **kwargs: drawn.append(curve.lost_motion_arcmin)
    )
    plot = tmp_path / "curve.png"
    assert (
        main(["estimate", str(loaded), "--ratio", "30", "--rated-torque", "2", "--method", method, "--plot", str(plot)])
        == 0
    )
    text = capsys.readouterr().out
    printed = float(re.search(r"lost motion:\s+([\d.]+) arcmin", text).group(1))
    assert len(drawn) == 1 and printed == round(drawn[0], 3)
    assert (
        main(
            [
                "estimate",
                str(loaded),
                "--ratio",
                "30",
                "--rated-torque",
                "2",
                "--method",
                method,
                "--plot",
                str(plot),
                "--json",
            ]
        )
        == 0
    )
    assert json.loads(capsys.readouterr().out)["lost_motion_arcmin"] == drawn[1]
