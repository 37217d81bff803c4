"""Choosing settings: the sweep's values and the centre of its working band (app/tuning.py)."""

import pytest

from app.tuning import band_centre, sweep_values, working_band


@pytest.mark.parametrize("lo, hi, steps, correct, centre", [
    (1, 4, 4, [False, True, True, False], 2),  # candidates: band 2..3, not 2.5
    (0, 3, 4, [True, True, False, False], 0),  # seed: band 0..1, not 0.5
    (1, 10, 4, [False, True, True, True], 7),  # values 1, 4, 7, 10: the middle swept value
])
def test_an_integer_setting_gets_a_whole_centre_it_was_swept_at(lo, hi, steps, correct, centre):
    values = sweep_values(lo, hi, steps, integer=True)
    found = band_centre(values, working_band(values, correct), integer=True)
    assert found == centre and type(found) is int and found in values


def test_a_float_setting_gets_the_middle_of_its_band_and_no_band_no_centre():
    values = sweep_values(0.5, 0.8, 4, integer=False)
    assert band_centre(values, working_band(values, [False, True, True, False]), integer=False) == pytest.approx(0.65)
    assert band_centre(values, working_band(values, [False] * 4), integer=False) is None
