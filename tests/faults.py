"""Defects on demand, for tests of what a batch does when the pipeline itself fails."""

import pipeline.recognize as recognize_module


def fail_first_segmentation(monkeypatch) -> None:
    """Make the pipeline raise ValueError("simulated defect") on the first image it segments in
    this process, as a defect showing on one image only would."""
    real = recognize_module.segment
    calls = []

    def segment(gray, settings):
        calls.append(1)
        if len(calls) == 1:
            raise ValueError("simulated defect")
        return real(gray, settings)
    monkeypatch.setattr(recognize_module, "segment", segment)
