"""Choosing settings: threshold advice from a box, the sweep's values and the centre of its working band (app/tuning.py)."""

from pathlib import Path

import numpy as np
import pytest

from signpose.app.tuning import (TuningError, band_centre, box_region, level_histogram, rect_mask, suggest_threshold,
                                 sweep_values, values_to_sweep, working_band)
from signpose.pipeline.image import read_image, to_gray
from signpose.pipeline.segment import normalize_levels
from signpose.pipeline.settings import Settings

SCENE = Path(__file__).resolve().parent.parent / "sample_images" / "scenes" / "scene_000.jpg"


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


def test_a_box_inside_the_sign_is_told_to_take_in_the_wall_and_no_setting_in_use_is_suggested():
    """A box dragged inside a sign, as 'drag a box on the sign' invites, has a ring around it that is
    sign too: the advice says to take in the wall, and never to switch to the normalisation in use."""
    image = np.full((200, 300), 60, np.uint8)
    image[50:150, 50:250] = 230  # the plaque
    inside = rect_mask((90, 80, 210, 120), 300, 200)  # well inside it
    advice = suggest_threshold(image, "minmax", inside, "rectangle")
    assert "draw it around the whole sign" in advice.warning and "minmax" not in advice.warning
    assert "normalization 'minmax'" in suggest_threshold(image, "scale", inside, "rectangle").warning
    around = suggest_threshold(image, "minmax", rect_mask((48, 48, 252, 152), 300, 200), "rectangle")
    assert around.warning is None and around.background_level < around.suggested_threshold < around.white_level


def test_the_histogram_of_a_dim_photo_stretched_by_minmax_has_no_comb():
    """A dim photo using 62 gray levels, stretched over 256 bins: binned as they were, three in four
    bins between its darkest and brightest came out empty."""
    dim = (60 + 0.55 * to_gray(read_image(SCENE))).astype(np.uint8)
    inside = rect_mask((0, 0, dim.shape[1], dim.shape[0]), dim.shape[1], dim.shape[0])
    histogram = level_histogram(dim[inside], normalize_levels(dim, "minmax"))
    assert histogram.sum() == dim.size
    occupied = histogram[np.flatnonzero(histogram)[0]:np.flatnonzero(histogram)[-1] + 1]
    assert (occupied == 0).sum() < 0.05 * occupied.size
    # where the pixels are: their normalised levels' median and mean, to a bin
    values = (dim - float(dim.min())) / (int(dim.max()) - int(dim.min()))
    centres = (np.arange(256) + 0.5) / 256
    assert np.average(centres, weights=histogram) == pytest.approx(values.mean(), abs=1 / 256)
    assert centres[np.searchsorted(np.cumsum(histogram), dim.size / 2)] == pytest.approx(np.median(values), abs=1 / 256)


def test_a_box_is_cut_to_the_image_and_one_outside_it_is_refused_as_given():
    inside, source = box_region((-20, 150, 50, 400), 300, 200)
    assert source == "rectangle" and inside.shape == (200, 300)
    assert np.array_equal(inside, rect_mask((0, 150, 50, 200), 300, 200))
    with pytest.raises(TuningError, match=r"rect \[299, 0, 400, 10\] does not cover at least 2x2 px of the 300x200"):
        box_region((299, 0, 400, 10), 300, 200)


def test_a_sweep_leaves_out_values_the_other_settings_refuse_and_names_an_end_out_of_range():
    settings = Settings(min_crop_size=128)
    assert values_to_sweep(settings, "max_crop_size", 0, 240, 4) == [0, 160, 240]  # 80 < min_crop_size
    with pytest.raises(TuningError, match=r"^hi \(7\): "):
        values_to_sweep(settings, "threshold", 0.5, 7, 3)
    with pytest.raises(TuningError, match="choose a numeric setting"):
        values_to_sweep(settings, "detector", 0, 1, 3)
