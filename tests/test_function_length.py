"""No function in the product's upper packages runs over 80 lines: a longer one hides
steps that deserve names (issue 53)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 80
PACKAGES = ("agent_client", "sim_server", "vacc")


def long_functions(source: str, name: str, limit: int = MAX_LINES) -> list[str]:
    """``name:line function (N lines)`` for every function or method over ``limit`` lines."""
    return [
        f"{name}:{node.lineno} {node.name} ({node.end_lineno - node.lineno + 1} lines)"
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.end_lineno - node.lineno + 1 > limit
    ]


@pytest.mark.parametrize("package", PACKAGES)
def test_no_function_over_80_lines(package: str) -> None:
    found = [hit for path in sorted((ROOT / package).rglob("*.py")) for hit in long_functions(path.read_text(), str(path.relative_to(ROOT)))]
    assert found == []


def test_the_check_counts_a_long_function() -> None:
    body = "".join(f"    x = {i}\n" for i in range(MAX_LINES))
    assert long_functions(f"def f():\n{body}", "m.py") == [f"m.py:1 f ({MAX_LINES + 1} lines)"]
    assert long_functions(f"def f():\n{body[: -len('    x = 79')-1]}", "m.py") == []
