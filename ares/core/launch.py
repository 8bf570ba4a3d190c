"""`python -m ares.core.launch module:Class`: run one node of the stack in this process.

The supervisor starts every process this way (exec'd, never forked), so a node is one class in
one module and the process table names it; nothing else is needed to make it runnable.
"""

from __future__ import annotations

import importlib
import sys

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


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        sys.exit("usage: python -m ares.core.launch module:Class")
    run_node(load(args[0]))


if __name__ == "__main__":
    main()
