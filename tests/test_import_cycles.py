"""No import cycles inside `prompose_grasp` or `sim`: a module that imports another must not be imported
by it, directly or through others. Checked on grimp's import graph (import-linter's own), imports under
`TYPE_CHECKING` included: a cycle that only type checkers see still ties the two modules into one
unit for a reader."""

from __future__ import annotations

import grimp


def _cycles(package: str) -> list[list[str]]:
    """The strongly connected components of more than one module in `package`'s import graph (Tarjan)."""
    graph = grimp.build_graph(package, cache_dir=None)
    modules = sorted(m for m in graph.modules if m == package or m.startswith(package + "."))
    inside = set(modules)
    edges = {m: sorted(inside & set(graph.find_modules_directly_imported_by(m))) for m in modules}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:  # iterative depth would do too; the graph is ~200 modules deep at most
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for m in modules:
        if m not in index:
            visit(m)
    return found


def test_no_import_cycle_in_the_library():
    cycles = _cycles("prompose_grasp")
    assert cycles == [], "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_no_import_cycle_in_the_simulator():
    cycles = _cycles("sim")
    assert cycles == [], "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)
