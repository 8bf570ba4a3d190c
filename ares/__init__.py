"""ARES: a supervisory stack for autonomous electric shuttles. Its layers, one folder each:

    core/    the bus, message schemas and the topic table, the node base, clocks, typed
             configuration, geometry, geodesy, routes; imports nothing of the project above it
    sim/     the simulated shuttle, its sensors and its 3-D world (a node package, beside
             perception, control, managers and blackbox)
    app/     the process table, run configuration, supervisor, stack runner, fleet, route import
    tools/   benches, harnesses, the headless run's evaluations and figures
    cli/     the `ares` command, on top of everything

The layers are kept by import-linter's contracts (pyproject.toml, checked in the test command).
"""
