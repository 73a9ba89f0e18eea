"""replay.unit_hints: the grid of radians told from the angles' own steps, and damaged values that are no grid."""

from __future__ import annotations

import warnings

import numpy as np

from online_backlash.replay.unit_hints import radian_counts

COUNTS = np.cumsum(np.tile([1, 1, 2, -1, -3, 1, 2], 10))


def test_counts_written_in_radians_are_told_and_degrees_are_not():
    assert radian_counts(COUNTS * 2 * np.pi / 16384) == 16384
    assert radian_counts(COUNTS * 360 / 16384) is None


def test_a_damaged_value_next_to_zero_is_no_grid_and_no_overflow():
    """A bit flip in a TDMS file left 2.7e-311 beside 2.67e-311 (found by the fuzz test of test_replay_tdms):
    the smallest step was a subnormal number and dividing by it overflowed."""
    angles = np.append(COUNTS * 2 * np.pi / 16384, [2.67159270e-311, 2.77981449e-312])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert radian_counts(angles) is None
