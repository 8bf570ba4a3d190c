"""`python -m ares.core.launch module:Class`: run one node of the stack in this process.

The supervisor starts every process this way (exec'd, never forked), so a node is one class in
one module and the process table names it; nothing else is needed to make it runnable.
"""

from __future__ import annotations

import importlib
import os
import signal
import sys

from ares.core import affinity
from ares.core.node import Node, run_node


def load(target: str) -> type[Node]:
    """The node class named `module:Class`."""
    module_name, _, class_name = target.partition(":")
    if not module_name or not class_name:
        raise ValueError(f"expected module:Class, got {target!r}")
    cls = getattr(importlib.import_module(module_name), class_name, None)
    if not (isinstance(cls, type) and issubclass(cls, Node)):
        raise ValueError(f"{target}: not a node class")
    return cls


FAULT_INJECTION_ENV = "ARES_FAULT_INJECTION"  # "1": a soak's processes (ares.tools.soak) take SIGUSR1


def spin_holding_the_gil(*_: object) -> None:
    """A fault a soak injects with SIGUSR1: the process busy-loops, holding the GIL, for ever. Its
    liveliness token (kept by Zenoh's threads) stays; only its stopped heartbeat tells."""
    sys.setswitchinterval(1e6)  # no other Python thread gets the GIL back
    while True:
        pass


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        sys.exit("usage: python -m ares.core.launch module:Class")
    affinity.pin_from_env()  # before the node's imports start their threads
    if os.environ.get(FAULT_INJECTION_ENV) == "1":  # never on a vehicle: only a soak sets it
        signal.signal(signal.SIGUSR1, spin_holding_the_gil)
    run_node(load(args[0]))


if __name__ == "__main__":
    main()
