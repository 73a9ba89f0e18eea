"""One drive, one play (issue 27): the flank lines where the flanks are fully engaged, partial crossings left out.

A train with two gaps in series (:mod:`online_backlash.simulation.two_mass_rig`, ``second_gap_deg``): an overrunning
load torque holds the load across the second gap for part of every rising stroke, so the load follows with
only part of the play crossed, then falls back onto the driving flank. That is not the estimators' model
(eq. 1 has one gap, the load on a flank or resting), and it is the measured gearhead's two-step crossing
(``docs/load-aware.md``). The play of the train is the full crossing: the rule
(:class:`~online_backlash.estimators.full_engagement.FullEngagement`) must recover it in the batch fit, the
recursive one and ``track``, and leave a drive with one gap as it was.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from online_backlash import BacklashRLS, VorosBacklash
from online_backlash.estimators.full_engagement import FOLLOWING, NO_FLANK, RESTING, FullEngagement
from online_backlash.history.store import HistoryStore
from online_backlash.log_fit import fit_batch, fit_recursive
from online_backlash.simulation.rig import simulate_rig
from online_backlash.simulation.two_mass_rig import simulate_two_mass
from online_backlash.stream import SampleChunk
from online_backlash.tracking import GearboxTracker

PLAY = 0.4
T0 = 1.7e9


def two_gaps(frequency_hz: float, overrun_nm: float, seed: int = 0, duration_s: float = 20.0):
    """The two-gap train on a 30 deg sine; the load torque pushes the load up (the way the rising stroke
    goes), ``overrun_nm`` at the bottom of the stroke, nothing at the top."""
    return simulate_two_mass(
        duration_s=duration_s, play_deg=PLAY, second_gap_deg=0.15, stiffness_nm_per_arcmin=1.0,
        viscous_nms_per_rad=0.05, frequency_hz=frequency_hz, seed=seed,
        external_torque_nm=lambda t: -overrun_nm * (1.0 - np.sin(2.0 * np.pi * frequency_hz * t)) / 2.0,
    )  # fmt: skip


def angles_only(chunk: SampleChunk) -> SampleChunk:
    return SampleChunk(chunk.time_s, chunk.motor_deg, chunk.load_deg, np.full(len(chunk), np.nan), chunk.after_gap)


def tracked(tmp_path, chunk: SampleChunk) -> dict:
    with HistoryStore(tmp_path / "w.db", create=True) as store:
        GearboxTracker(store, "g", 30.0, every_s=10.0).track_chunks(
            [chunk], "log", key="k" * 64, clock_offset=lambda first: T0
        )
        return vars(store.estimates("g")[-1])


@pytest.mark.parametrize(("frequency_hz", "overrun_nm"), [(0.5, 0.3), (0.2, 0.3), (0.5, 0.5)])
def test_a_train_with_two_gaps_gives_its_whole_play_batch_recursive_and_track(tmp_path, frequency_hz, overrun_nm):
    rec = two_gaps(frequency_hz, overrun_nm)
    u = rec.motor_deg / rec.ratio
    paper = VorosBacklash(origin="first").fit(u, rec.load_deg)  # every sample in the lines: the two levels mixed
    assert paper.backlash_ < 0.8 * PLAY
    chunk = angles_only(rec.to_chunk())
    found = [fit_batch(chunk, rec.ratio)[0].as_dict(), fit_recursive([chunk], rec.ratio)[0].as_dict()]
    found.append(tracked(tmp_path, chunk))
    for d in found:
        assert d["play_method"] == "kinematic" and d["play_observable"] is True
        # the wind-up of the two stiff meshes is a few thousandths of a degree
        assert d["backlash_deg"] == pytest.approx(PLAY, abs=0.02)
        assert abs(d["backlash_deg"] - PLAY) <= 2 * d["backlash_std_deg"]


def test_the_partial_crossings_are_what_is_left_out():
    """Rising, the load follows with the first gap crossed only until, near the top of the stroke, the load
    torque gives way and it falls back across the second one: the samples left out are those at the lower
    level, short of the full crossing by the second gap; what is kept of both flanks lies at the same
    positions (the top of the stroke)."""
    rec = two_gaps(0.5, 0.3)
    u, y = rec.motor_deg / rec.ratio, rec.load_deg
    judge = FullEngagement()
    seen = judge.fit(u, y)
    assert set(np.unique(seen)) <= {RESTING, FOLLOWING, NO_FLANK}
    lost = u - y  # the lost motion, degrees
    rising = np.gradient(rec.u_true_deg) > 0
    kept, left_out = rising & (seen == FOLLOWING), rising & (seen == NO_FLANK)
    assert kept.mean() > 0.05 and left_out.mean() > 0.2
    assert np.median(lost[kept]) - np.median(lost[left_out]) == pytest.approx(0.15, abs=0.02)  # the second gap
    falling_kept = ~rising & (seen == FOLLOWING)
    assert np.min(rec.u_true_deg[falling_kept]) > np.min(rec.u_true_deg[kept]) - 1.0  # positions matched
    assert judge.full_width_deg_ == pytest.approx(PLAY, abs=0.02)
    assert 0.02 < judge.shortfall_deg_ < 0.15


@pytest.mark.parametrize("bits", [14, 17, 20])
@pytest.mark.parametrize("play_deg", [1.0 / 60.0, 0.5])
def test_a_drive_with_one_gap_is_left_as_it_was(bits, play_deg):
    """The estimators' own model, continuous rotation with reversals: hardly a sample is left out (the first
    visits of a position the other flank never saw are kept, nothing says otherwise) and the plays are those
    of the paper's lines, batch and recursive."""
    rec = simulate_rig(duration_s=20.0, play_deg=play_deg, motor_bits=bits + 4, load_bits=bits, seed=bits)
    u, y = rec.motor_deg / rec.ratio, rec.load_deg
    assert np.mean(FullEngagement().fit(u, y) == NO_FLANK) < 0.02
    plain, full = (VorosBacklash(origin="first", full_engagement=on).fit(u, y) for on in (False, True))
    assert full.backlash_ == pytest.approx(plain.backlash_, abs=max(plain.backlash_std_, 1e-4))
    recursive = []
    for on in (False, True):
        est = BacklashRLS(full_engagement=on)
        est.learn_many(u, y)
        recursive.append(est.backlash_)
    assert recursive[1] == pytest.approx(recursive[0], abs=max(plain.backlash_std_, 1e-4))


def test_a_stream_is_judged_as_it_comes_and_resumes_from_its_saved_state():
    """:meth:`FullEngagement.update` after :meth:`~FullEngagement.fit` judges the next samples against the
    strokes completed so far: on a steady periodic record as a whole record does, past its first strokes;
    a state saved as JSON and restored judges the rest alike, bit for bit."""
    rec = two_gaps(0.5, 0.3, duration_s=30.0)
    u, y = rec.motor_deg / rec.ratio, rec.load_deg
    whole = FullEngagement().fit(u, y)
    stream = FullEngagement()
    head = stream.fit(u[:10_000], y[:10_000])
    middle = stream.update(u[10_000:20_000], y[10_000:20_000])
    saved = FullEngagement.from_state(json.loads(json.dumps(stream.state_dict())))
    tail = [judge.update(u[20_000:], y[20_000:]) for judge in (stream, saved)]
    assert np.array_equal(tail[0], tail[1]) and saved.shortfall_deg_ == stream.shortfall_deg_
    streamed = np.concatenate((head, middle, tail[0]))
    assert np.mean(streamed[12_000:] == whole[12_000:]) > 0.97


def test_before_its_bands_are_set_a_stream_is_held_and_left_to_the_model():
    """A stream judged sample by sample from its start (a recursive estimator started cold): the first
    samples are held until they set the still bands, and left to the model (:data:`RESTING`) meanwhile."""
    rec = two_gaps(0.5, 0.3)
    u, y = rec.motor_deg / rec.ratio, rec.load_deg
    judge = FullEngagement()
    first = [int(judge.update(u[i : i + 1], y[i : i + 1])[0]) for i in range(500)]
    assert set(first) == {RESTING} and not judge.settled_
    rest = judge.update(u[500:12_000], y[500:12_000])
    assert judge.settled_ and np.any(rest == NO_FLANK)
