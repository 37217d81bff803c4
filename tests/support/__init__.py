"""Helpers the tests share (and tools/screenshot.py, bench/load.py): servers, the browser, synthetic images."""
