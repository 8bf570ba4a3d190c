"""No import cycle between the project's modules, counting the imports inside functions too (a
lazy import hides a cycle from the interpreter at start, not from a reader): grimp's graph of
import-linter's root packages, whose strongly connected components must all be single modules."""

from __future__ import annotations

import tomllib
from pathlib import Path

import grimp

REPO = Path(__file__).resolve().parents[1]
ROOT_PACKAGES = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]["root_packages"]


def cycles(imports: dict[str, set[str]]) -> list[list[str]]:
    """The groups of modules that import each other round (Tarjan's strongly connected components
    of more than one module, or of one importing itself), iteratively: the graph has thousands of
    modules."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in sorted(imports):
        if root in index:
            continue
        work = [(root, iter(sorted(imports[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            module, pending = work[-1]
            step = next(pending, None)
            if step is not None:
                if step not in index:
                    index[step] = low[step] = len(index)
                    stack.append(step)
                    on_stack.add(step)
                    work.append((step, iter(sorted(imports.get(step, ())))))
                elif step in on_stack:
                    low[module] = min(low[module], index[step])
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[module])
            if low[module] == index[module]:
                group = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    group.append(member)
                    if member == module:
                        break
                if len(group) > 1 or module in imports.get(module, ()):
                    found.append(sorted(group))
    return found


def test_cycles_finds_a_ring_and_a_self_import_and_nothing_in_a_tree():
    tree = {"a": {"b", "c"}, "b": {"c"}, "c": set()}
    assert cycles(tree) == []
    ring = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(ring) == [["a", "b", "c"]]
    assert cycles({"a": {"a"}, "b": set()}) == [["a"]]


def test_no_module_is_in_an_import_cycle():
    graph = grimp.build_graph(*ROOT_PACKAGES, cache_dir=None)
    imports = {module: set(graph.find_modules_directly_imported_by(module)) for module in graph.modules}
    found = cycles(imports)
    described = []
    for group in found:
        members = set(group)
        edges = [
            f"{a} -> {b} (line {', '.join(str(d['line_number']) for d in details)})"
            for a in group
            for b in sorted(imports[a] & members)
            for details in [graph.get_import_details(importer=a, imported=b)]
        ]
        described.append(f"{' <-> '.join(group)}: " + "; ".join(edges))
    assert not found, "import cycles:\n" + "\n".join(described)
