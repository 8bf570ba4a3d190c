"""Composition-layer harnesses: they run algorithms of several packages together in one process,
for experiments, calibration and tests."""
