"""Fixtures the test modules share. Plain helpers (servers, the browser, synthetic images) are in
tests.support, imported by name; what needs pytest's set-up and tear-down is here.

Markers (pyproject.toml, docs/testing.md): a module of tests that start real servers or drive the
browser says so with a module-level `pytestmark`; single tests that take seconds are `slow`."""

from __future__ import annotations

from collections.abc import Callable

import pytest

import signpose.pipeline.recognize as recognize_module
from signpose.pipeline.settings import Settings
from tests.support.browser_harness import FAILED

SegmentationFault = Callable[[Callable[[int, Settings], bool]], None]


@pytest.fixture
def fail_segmentation(monkeypatch) -> SegmentationFault:
    """A defect on demand, for tests of what a batch does when the pipeline itself fails: called with
    `when`, it makes the pipeline raise ValueError("simulated defect") when it segments an image in
    this process and `when(n, settings)` holds, n counting its segmentations from 1 (a defect that
    shows on some images or settings only). Undone after the test."""
    def install(when: Callable[[int, Settings], bool]) -> None:
        real = recognize_module.segment
        calls = []

        def segment(gray, settings):
            calls.append(1)
            if when(len(calls), settings):
                raise ValueError("simulated defect")
            return real(gray, settings)
        monkeypatch.setattr(recognize_module, "segment", segment)
    return install


@pytest.fixture
def fail_first_segmentation(fail_segmentation: SegmentationFault) -> None:
    """`fail_segmentation` on the first image segmented in this process only, from the test's start."""
    fail_segmentation(lambda n, _: n == 1)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    """Records on the test whether its call failed, for fixtures that keep state across tests
    (the browser tests' shared page is opened again after a failure)."""
    report = yield
    if report.when == "call" and report.failed:
        item.stash[FAILED] = True
    return report
