"""Defects on demand, for tests of what a batch does when the pipeline itself fails."""

from collections.abc import Callable

import signpose.pipeline.recognize as recognize_module
from signpose.pipeline.settings import Settings


def fail_segmentation(monkeypatch, when: Callable[[int, Settings], bool]) -> None:
    """Make the pipeline raise ValueError("simulated defect") when it segments an image in this
    process and `when(n, settings)` holds, n counting its segmentations from 1: a defect that shows
    on some images or settings only."""
    real = recognize_module.segment
    calls = []

    def segment(gray, settings):
        calls.append(1)
        if when(len(calls), settings):
            raise ValueError("simulated defect")
        return real(gray, settings)
    monkeypatch.setattr(recognize_module, "segment", segment)


def fail_first_segmentation(monkeypatch) -> None:
    """`fail_segmentation` on the first image segmented only."""
    fail_segmentation(monkeypatch, lambda n, _: n == 1)
