"""Descriptor matching: the two nearest library descriptors found by one matrix product."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from signpose.pipeline.features import detect, library_features
from signpose.pipeline.image import read_image, to_gray
from signpose.pipeline.match import nearest_two
from signpose.pipeline.settings import preset

SCENES = Path(__file__).resolve().parents[1] / "sample_images" / "scenes"


@pytest.mark.parametrize("name", ["scene_000.jpg", "scene_005.jpg"])
def test_the_nearest_two_are_bfmatchers_to_the_bit(library, name):
    """The matrix product's distances are batchDistance's bit for bit, so the ratio test keeps the
    same matches, on a frame with a sign and one without, against every library sign."""
    settings = preset("default")
    query = detect(to_gray(read_image(SCENES / name)), settings).descriptors
    assert len(query) > 100
    for train in library_features(library, settings).values():
        distances, indices = nearest_two(query, train.descriptors, cv2.NORM_L2)
        expected, expected_indices = cv2.batchDistance(query, train.descriptors, cv2.CV_32F,
                                                       normType=cv2.NORM_L2, K=2)
        assert np.array_equal(distances, expected)
        kept = distances[:, 0] < settings.ratio * distances[:, 1]
        assert kept.any()
        assert np.array_equal(indices[kept, 0], expected_indices[kept, 0])
