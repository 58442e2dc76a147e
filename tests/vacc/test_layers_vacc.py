"""The import layers: vacc's modules form no cycle, and no product package imports scripts/.

Every import counts, at module level or inside a function (an import moved into a
function still ties the two modules together; it only hides the cycle until run time).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PRODUCT = ("vacc", "agent_client", "sim_server", "protocol", "energy")


def _imports(path: Path, package: str) -> set[str]:
    """The modules ``path`` imports anywhere in it, as dotted names (``from vacc import x``: vacc.x too)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            # relative (level > 0): from the module's own dotted name, drop `level` parts
            here = [package, *path.relative_to(ROOT / package).with_suffix("").parts]
            base = ".".join(here[: -node.level] if node.level else [])
            module = ".".join(p for p in (base, node.module or "") if p)
            names.add(module)
            names.update(f"{module}.{a.name}" for a in node.names)
    return names


def _vacc_graph() -> dict[str, set[str]]:
    modules = {f"vacc.{p.stem}" for p in (ROOT / "vacc").glob("*.py") if p.stem != "__init__"}
    return {f"vacc.{p.stem}": (_imports(p, "vacc") & modules) - {f"vacc.{p.stem}"} for p in (ROOT / "vacc").glob("*.py") if p.stem != "__init__"}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a path that ends where it starts, or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt) :] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        state[node] = 2
        path.pop()
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_the_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_vacc_modules_import_each_other_without_a_cycle():
    graph = _vacc_graph()
    assert {"vacc.runs", "vacc.evaluate", "vacc.figures", "vacc.safety"} <= set(graph)
    cycle = _cycle(graph)
    assert cycle is None, " -> ".join(cycle or [])


def test_runs_is_below_the_suites_tables_and_figures():
    graph = _vacc_graph()
    assert graph["vacc.runs"] <= {"vacc.stats", "vacc.paths"}, graph["vacc.runs"]
    for upper in ("vacc.evaluate", "vacc.figures", "vacc.safety", "vacc.tables", "vacc.random_suite"):
        assert "vacc.runs" in graph[upper], upper


def test_no_product_package_imports_scripts():
    offenders = [
        f"{path.relative_to(ROOT)}: {name}"
        for package in PRODUCT
        for path in sorted((ROOT / package).rglob("*.py"))
        for name in sorted(_imports(path, package))
        if name == "scripts" or name.startswith("scripts.")
    ]
    assert offenders == []
