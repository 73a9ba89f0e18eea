"""``online-backlash listen``: live runs on a virtual CAN bus and a pseudo terminal, ended by
Ctrl-C (SIGINT) or ``--duration``; the JSON summary; the raw log replays to the same estimate."""

from __future__ import annotations

import fcntl
import json
import os
import signal
import struct
import termios
import threading
import time
import tty

import can
import pytest
from can.interfaces.virtual import channels

from online_backlash.cli import main
from online_backlash.codecs.dbc import RIG_DBC, DbcDecoder
from online_backlash.rig import simulate_rig
from online_backlash.rig_logs import rig_can_frames, rig_serial_records

ESTIMATE_KEYS = {
    "backlash_deg", "backlash_arcmin", "c_left_deg", "c_right_deg", "m_left", "m_right",
    "samples", "residual_rms_deg", "method", "backlash_std_deg", "n_reversals",
}
COUNTERS = {"frames", "samples", "corrupt", "skipped", "gaps"}


@pytest.fixture(scope="module")
def rec():
    return simulate_rig(duration_s=4.0, rate_hz=1000.0, reversal_s=(0.4, 0.8), seed=11)


def wait_for(condition, limit_s=30.0):
    deadline = time.monotonic() + limit_s
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.01)


def interrupt_when(condition):
    """From a thread: wait for ``condition``, then press Ctrl-C (SIGINT to this process)."""

    def run():
        wait_for(condition)
        time.sleep(0.2)
        os.kill(os.getpid(), signal.SIGINT)

    thread = threading.Thread(target=run)
    thread.start()
    return thread


def test_listen_can_until_ctrl_c_then_estimate_the_raw_log(tmp_path, capsys, rec):
    frames = list(rig_can_frames(rec, DbcDecoder(RIG_DBC, "MotorAngle.Count", "LoadAngle.Count"), 1.7e9, skew_s=1e-4))
    frames[777].data[0] ^= 0x40  # one corrupt frame

    def send():
        wait_for(lambda: len(channels.get("cli-can", [])) >= 1)  # the listener's bus is open
        tx = can.Bus(interface="virtual", channel="cli-can", preserve_timestamps=True)
        for f in frames:
            tx.send(f)
        wait_for(lambda: all(q.empty() for q in channels.get("cli-can", [])))
        tx.shutdown()

    sender = threading.Thread(target=send)
    sender.start()
    stopper = interrupt_when(lambda: not sender.is_alive())
    argv = ["listen", "can", "--interface", "virtual", "--channel", "cli-can", "--dbc", "rig", "--motor-signal", "MotorAngle.Count",
            "--load-signal", "LoadAngle.Count", "--ratio", "30", "--raw-log", str(tmp_path / "raw"), "--json"]
    assert main(argv) == 0
    sender.join()
    stopper.join()
    out = capsys.readouterr()
    live = json.loads(out.out)
    assert ESTIMATE_KEYS | COUNTERS | {"unpaired", "pair_skew_max_s"} <= set(live)
    assert live["frames"] == len(frames) and live["corrupt"] == 1 and live["unpaired"] == 1
    assert live["samples"] == rec.time_s.size - 1 and live["method"] == "recursive"
    assert live["backlash_deg"] == pytest.approx(0.5, abs=0.05)
    assert live["pair_skew_max_s"] == pytest.approx(1e-4, abs=1e-6)
    assert "backlash" in out.err and "samples/s" in out.err  # the status line

    assert len(list((tmp_path / "raw").iterdir())) == 1
    assert main(["estimate", str(tmp_path / "raw"), "--dbc", "rig", "--motor-signal", "MotorAngle.Count", "--load-signal", "LoadAngle.Count",
                 "--ratio", "30", "--json"]) == 0
    replayed = json.loads(capsys.readouterr().out)
    assert {k: replayed[k] for k in ESTIMATE_KEYS} == {k: live[k] for k in ESTIMATE_KEYS}


def pending_input(fd):
    return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]


@pytest.mark.parametrize("fmt", ["ascii", "binary"])
def test_listen_serial_on_a_pty_then_estimate_the_capture(tmp_path, capsys, rec, fmt):
    cpr = ["--motor-cpr", "16384", "--load-cpr", "131072"]
    payload = b"".join(rig_serial_records(rec, fmt, 16384, 131072))
    payload = payload[:5000] + b"\x00noise\n" + payload[5000:]
    master, slave = os.openpty()
    tty.setraw(slave)  # no line discipline on the bytes, even before the CLI has opened the port
    written = threading.Event()

    def write():
        # the capture file appears once the CLI has opened the port (which flushes its input)
        wait_for(lambda: (tmp_path / "raw").is_dir() and any((tmp_path / "raw").iterdir()))
        for i in range(0, len(payload), 4096):
            os.write(master, payload[i : i + 4096])
        written.set()

    writer = threading.Thread(target=write)
    writer.start()
    stopper = interrupt_when(lambda: written.is_set() and pending_input(slave) == 0)
    argv = ["listen", "serial", "--port", os.ttyname(slave), "--baud", "115200", "--format", fmt, "--ratio", "30",
            "--raw-log", str(tmp_path / "raw"), "--json", *cpr]
    try:
        assert main(argv) == 0
    finally:
        writer.join()
        stopper.join()
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
    argv = ["listen", "serial", "--port", "loop://", "--format", "ascii", "--ratio", "30", "--raw-log", str(tmp_path), "--duration", "0.3"]
    assert main(argv) == 1
    assert "error: serial loop://: no samples received (frames 0" in capsys.readouterr().err


def test_listen_can_bad_interface_is_a_clear_error(tmp_path, capsys):
    argv = ["listen", "can", "--interface", "nonexistent", "--channel", "x", "--dbc", "rig", "--motor-signal", "RigAngles.Motor",
            "--load-signal", "RigAngles.Load", "--ratio", "30", "--raw-log", str(tmp_path)]
    assert main(argv) == 1
    assert "error: cannot open CAN interface 'nonexistent'" in capsys.readouterr().err
