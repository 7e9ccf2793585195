"""The observer-gym benchmark: versioned suites of sensor levels per system
(``suites/<version>/<system>.toml``), normalised scores, runs and their check
(docs/benchmark.md)."""
