"""signpose's tests; a package so that they import their helpers (tests.support) by a real name."""
