"""``online-backlash listen``: live runs on a virtual CAN bus and a pseudo terminal, ended by
Ctrl-C (SIGINT) or ``--duration``; the JSON summary; the raw log replays to the same estimate."""

from __future__ import annotations

import io
import json
import os
import signal
import sys
import threading
import tty

import pytest
from live_run import LIMIT_S, run_live, send_frames, wait_until
from rig_can import RIG_CAN

from online_backlash.cli import main
from online_backlash.cli._live import CTRL_C_READY, ctrl_c_ends_the_run
from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.rig_logs import rig_can_frames, rig_serial_records

ESTIMATE_KEYS = {
    "backlash_deg",
    "backlash_arcmin",
    "c_left_deg",
    "c_right_deg",
    "m_left",
    "m_right",
    "samples",
    "residual_rms_deg",
    "method",
    "backlash_std_deg",
    "n_reversals",
}
COUNTERS = {"frames", "samples", "corrupt", "skipped", "gaps"}


@pytest.fixture(scope="module")
def rec():
    return simulate_rig(duration_s=4.0, rate_hz=1000.0, reversal_s=(0.4, 0.8), seed=11)


def test_listen_can_until_ctrl_c_then_estimate_the_raw_log(tmp_path, capsys, rec):
    frames = list(rig_can_frames(rec, DbcDecoder(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count"), 1.7e9, skew_s=1e-4))
    frames[777].data[0] ^= 0x40  # one corrupt frame
    argv = [
        "listen",
        "can",
        "--interface",
        "virtual",
        "--channel",
        "cli-can",
        *RIG_CAN,
        "--ratio",
        "30",
        "--raw-log",
        str(tmp_path / "raw"),
        "--json",
    ]
    # Ctrl-C right after the last frame is sent: the frames still waiting on the bus are learned too
    assert run_live(argv, lambda _: send_frames("cli-can", frames)) == 0
    out = capsys.readouterr()
    live = json.loads(out.out)
    assert ESTIMATE_KEYS | COUNTERS | {"unpaired", "pair_skew_max_s"} <= set(live)
    assert live["frames"] == len(frames) and live["corrupt"] == 1 and live["unpaired"] == 1
    assert live["samples"] == rec.time_s.size - 1 and live["method"] == "recursive"
    assert live["backlash_deg"] == pytest.approx(0.5, abs=0.05)
    assert live["pair_skew_max_s"] == pytest.approx(1e-4, abs=1e-6)
    assert "can cli-can: listening; Ctrl-C ends the run with its summary\n" in out.err
    assert f"{live['samples']} samples," in out.err and "samples/s" in out.err  # the status line

    assert len(list((tmp_path / "raw").iterdir())) == 1
    assert main(["estimate", str(tmp_path / "raw"), *RIG_CAN, "--ratio", "30", "--json"]) == 0
    replayed = json.loads(capsys.readouterr().out)
    assert {k: replayed[k] for k in ESTIMATE_KEYS} == {k: live[k] for k in ESTIMATE_KEYS}


@pytest.mark.parametrize("fmt", ["ascii", "binary"])
def test_listen_serial_on_a_pty_then_estimate_the_capture(tmp_path, capsys, rec, fmt):
    cpr = ["--motor-cpr", "16384", "--load-cpr", "131072"]
    payload = b"".join(rig_serial_records(rec, fmt, 16384, 131072))
    payload = payload[:5000] + b"\x00noise\n" + payload[5000:]
    master, slave = os.openpty()
    tty.setraw(slave)  # no line discipline on the bytes, even before the CLI has opened the port

    def captured() -> int:
        return sum(p.stat().st_size for p in (tmp_path / "raw").iterdir())

    def write(_):
        for i in range(0, len(payload), 4096):
            os.write(master, payload[i : i + 4096])
        # a pty hands bytes on in the kernel's own time: Ctrl-C once the capture has them all (each read
        # is captured, then parsed and learned before the run looks for a Ctrl-C)
        wait_until(lambda: captured() == len(payload), "every byte captured")

    argv = [
        "listen",
        "serial",
        "--port",
        os.ttyname(slave),
        "--baud",
        "115200",
        "--format",
        fmt,
        "--ratio",
        "30",
        "--raw-log",
        str(tmp_path / "raw"),
        "--json",
        *cpr,
    ]
    try:
        assert run_live(argv, write) == 0
    finally:
        os.close(master)
        os.close(slave)
    live = json.loads(capsys.readouterr().out)
    assert ESTIMATE_KEYS | COUNTERS <= set(live)
    assert live["samples"] == rec.time_s.size - 1 and live["corrupt"] == 2  # the noise splits one record in two
    (capture,) = sorted((tmp_path / "raw").iterdir())
    assert capture.read_bytes() == payload
    assert main(["estimate", str(tmp_path / "raw"), "--serial-format", fmt, "--ratio", "30", "--json", *cpr]) == 0
    replayed = json.loads(capsys.readouterr().out)
    assert {k: replayed[k] for k in ESTIMATE_KEYS} == {k: live[k] for k in ESTIMATE_KEYS}


def test_listen_serial_duration_and_no_data_is_a_clear_error(tmp_path, capsys):
    argv = ["listen", "serial", "--port", "loop://", "--format", "ascii", "--ratio", "30", "--raw-log", str(tmp_path)]
    argv += ["--duration", "0.3"]
    assert main(argv) == 1
    assert "error: serial loop://: no samples received (frames 0" in capsys.readouterr().err


def test_listen_can_bad_interface_is_a_clear_error(tmp_path, capsys):
    argv = [
        "listen",
        "can",
        "--interface",
        "nonexistent",
        "--channel",
        "x",
        "--dbc",
        "rig",
        "--motor-signal",
        "RigAngles.Motor",
        "--load-signal",
        "RigAngles.Load",
        "--ratio",
        "30",
        "--raw-log",
        str(tmp_path),
    ]
    assert main(argv) == 1
    assert "error: cannot open CAN interface 'nonexistent'" in capsys.readouterr().err


def test_the_listening_line_comes_once_ctrl_c_is_handled(monkeypatch):
    """A Ctrl-C the moment the line is written ends the run (the handler is already in place), never the process."""
    stopped = threading.Event()

    class CtrlCOnTheLine(io.StringIO):
        def write(self, text: str) -> int:
            if CTRL_C_READY in text:
                os.kill(os.getpid(), signal.SIGINT)
            return super().write(text)

    monkeypatch.setattr(sys, "stderr", CtrlCOnTheLine())
    with ctrl_c_ends_the_run(stopped.set, "can x"):
        assert stopped.wait(LIMIT_S)
    assert sys.stderr.getvalue() == f"can x: listening; {CTRL_C_READY}\n"
