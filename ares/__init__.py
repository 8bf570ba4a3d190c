"""ARES core: bus, message schemas, node base, clock, config, supervisor, CLI, simulator."""
