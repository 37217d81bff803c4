import numpy as np

import pytest

from signpose.pipeline.segment import expand_box, label_components, normalize_gray, segment, threshold_mask
from signpose.pipeline.settings import Settings


def scene_with_plaques():
    """A dark wall with a big white door (left) and a smaller plaque (right)."""
    img = np.full((240, 320), 60, np.uint8)
    img[20:230, 10:110] = 230  # door: 21000 px
    img[100:140, 180:300] = 250  # plaque: 4800 px
    img[112:128, 200:280] = 0  # black text inside the plaque
    return img


def test_normalisations():
    g = np.array([[50, 100], [150, 200]], np.uint8)
    assert np.allclose(normalize_gray(g, "scale"), g / 255)
    assert np.allclose(normalize_gray(g, "minmax"), [[0, 1 / 3], [2 / 3, 1]])
    assert not normalize_gray(np.full((4, 4), 7, np.uint8), "minmax").any()


def test_blobs_largest_first_and_crops_with_margin():
    seg = segment(scene_with_plaques(), Settings(threshold=0.6, candidates=3, crop_margin=0.1))
    assert [b.bbox for b in seg.blobs] == [(10, 20, 110, 230), (180, 100, 300, 140)]
    assert seg.crops[1] == (168, 96, 312, 144)
    assert seg.mask.dtype == np.uint8 and seg.mask.max() == 255


def test_paper_keeps_only_the_largest_blob_and_high_threshold_gates_glare():
    img = scene_with_plaques()
    assert len(segment(img, Settings(candidates=1)).blobs) == 1
    seg = segment(img, Settings(threshold=0.6, high_threshold=0.95, candidates=3))
    assert [b.bbox for b in seg.blobs] == [(10, 20, 110, 230)]  # the 250-level plaque is above the gate


def test_expand_box_clips_to_image():
    assert expand_box((0, 0, 10, 10), 0.5, 12, 12) == (0, 0, 12, 12)


def test_all_black_image_has_no_blobs():
    assert segment(np.zeros((50, 50), np.uint8), Settings()).blobs == []


@pytest.mark.parametrize("normalization", ["scale", "minmax"])
@pytest.mark.parametrize("threshold, high_threshold", [(0.75, None), (0.5, 0.9), (0.6, 0.61)])
def test_mask_is_the_threshold_of_the_normalised_gray(normalization, threshold, high_threshold):
    # segment thresholds uint8 levels through a lookup table; it must agree pixel for pixel
    # with thresholding the float image the figures show, edge levels included.
    img = np.random.default_rng(0).integers(30, 221, (120, 160), dtype=np.uint8)
    seg = segment(img, Settings(normalization=normalization, threshold=threshold, high_threshold=high_threshold))
    expected = threshold_mask(normalize_gray(img, normalization), threshold, high_threshold)
    assert np.array_equal(seg.mask, expected)


def test_components_beyond_uint16_are_all_labelled():
    # isolated pixels on every other row and column: 240 x 320 = 76800 components, more than
    # uint16 labels hold
    mask = np.zeros((480, 640), np.uint8)
    mask[::2, ::2] = 255
    labels, stats = label_components(mask)
    assert len(stats) == 76801 and labels.max() == 76800
    assert (stats[1:, 4] == 1).all()
    assert labels[478, 638] == 76800 and labels[1, 1] == 0


def test_few_components_keep_their_stats():
    labels, stats = label_components(segment(scene_with_plaques(), Settings(threshold=0.6)).mask)
    assert labels.dtype == np.uint16
    assert sorted(stats[1:, 4]) == [4800 - 16 * 80, 21000]
    assert labels[25, 15] != labels[105, 185] and labels[0, 0] == 0
