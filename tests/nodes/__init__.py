"""Tiny node processes used by the tests (run as `python -m tests.nodes.<module>`)."""
