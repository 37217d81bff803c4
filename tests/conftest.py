"""Fixtures the test modules share. Plain helpers (servers, the browser, synthetic images) are in
tests.support, imported by name; what needs pytest's set-up and tear-down is here.

Markers (pyproject.toml, docs/testing.md): a module of tests that start real servers or drive the
browser says so with a module-level `pytestmark`; single tests that take seconds are `slow`."""

from __future__ import annotations

import signal
from collections.abc import Callable

import pytest

import signpose.pipeline.recognize as recognize_module
from signpose.pipeline.library import Library, load_library
from signpose.pipeline.settings import Settings
from tests.support import browser_harness as harness
from tests.support.browser_harness import FAILED

SegmentationFault = Callable[[Callable[[int, Settings], bool]], None]

# A run started in the background of a non-interactive shell ignores SIGINT, and the commands these
# tests start would inherit that and never see their Ctrl-C. Handled here, it is default in them.
signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session")
def library() -> Library:
    """The sample library, read once per test process: its signs' features, and their simulated steep
    views (0.7 s of CPU), are computed once per settings for every test that recognizes with it, as a
    server computes them once for its library. Read-only: a test that changes a library or counts what
    loading one computes loads its own, and a module whose tests need another library gives its own
    `library` fixture."""
    return load_library()


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


# The browser tests' page: a module that drives the browser gives `base`, its server's URL.

@pytest.fixture(scope="module")
def browser(base):
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = harness.launch(p)
        yield browser
        browser.close()


@pytest.fixture(scope="module")
def shared_page(browser, base):
    """The module's tests share one page (opening one takes 2-3 s); `page` opens it again after a
    test that failed, closed it or left errors in it."""
    held = harness.SharedPage(browser, base)
    yield held
    held.close()


@pytest.fixture
def fresh_page(browser, base, shared_page):
    """A page of its own, for a test that needs one just loaded or leaves listeners on it (dialogs,
    file choosers). The shared page is closed first: what it holds open (a dialog, a request on its
    way) would act on the server beside the test's page."""
    shared_page.close()
    page = harness.open_page(browser, base)
    yield page
    harness.close_page(page)


@pytest.fixture
def page(shared_page, request):
    page = shared_page.take()
    yield page
    shared_page.give_back(failed=request.node.stash.get(harness.FAILED, False))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    """Records on the test whether its call failed, for fixtures that keep state across tests
    (the browser tests' shared page is opened again after a failure)."""
    report = yield
    if report.when == "call" and report.failed:
        item.stash[FAILED] = True
    return report
