"""The benchmarks behind `ares bench`: bus (ares.tools.bench.bus), path (ares.tools.bench.path); the black box's
are ares.tools.bench.blackbox_store and ares.tools.bench.blackbox_api. Figures are measured and reported, never
asserted in tests."""
