"""On quantised encoder data what ``diagnose`` finds does not hang on the last bits of its base fit.

A motor that has not moved a count between two samples puts eq. (5)-(6) on a tie on the engaged
flank; evaluated in floating point, the tie went either way with the parameters' last bits, and the
engaged samples (the dead band's exits and entries, the gating of the compliance, the held columns)
flickered with them. On run20 of the shared recordings a change of 1e-12 of the base fit's left
slope and width turned two terms into three; the simulation now keeps the engaged state where the
input has not moved (:func:`online_backlash.model.simulate_switching`).
"""

from __future__ import annotations

import json

import pytest
from davinci_runs import DAVINCI, UNITS, WITH_TORQUE

from online_backlash.cli import main
from online_backlash.diagnostics import loop
from online_backlash.model import BacklashParams

RUN20 = DAVINCI / "tool4_L_run20_0.3Hz_torque10pct.csv"
ARGS = [*UNITS, "--columns", WITH_TORQUE, "--json"]


def _diagnosed(capsys, monkeypatch, change: float) -> dict:
    fit = loop.VorosBacklash.fit

    def nudged(self, u, y):
        est = fit(self, u, y)
        p = est.params_
        est.params_ = BacklashParams(p.m_left * (1 + change), p.c_left * (1 - change), p.m_right, p.c_right)
        return est

    monkeypatch.setattr(loop.VorosBacklash, "fit", nudged)
    assert main(["diagnose", str(RUN20), *ARGS]) == 0
    return json.loads(capsys.readouterr().out)


def test_a_last_bit_change_of_the_base_fit_changes_nothing_found(capsys, monkeypatch):
    assert RUN20.exists(), f"measured data missing: {RUN20}"
    plain = _diagnosed(capsys, monkeypatch, 0.0)
    monkeypatch.undo()
    nudged = _diagnosed(capsys, monkeypatch, 1e-12)
    for key in ("effects", "unexplained"):
        assert [e["name"] for e in nudged[key]] == [e["name"] for e in plain[key]]
    assert nudged["rms_after_deg"] == pytest.approx(plain["rms_after_deg"], rel=1e-6)
    assert nudged["backlash_after_deg"] == pytest.approx(plain["backlash_after_deg"], rel=1e-6)
