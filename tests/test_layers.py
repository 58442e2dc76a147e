"""The packages' layers hold: ``protocol`` and ``energy`` at the bottom, ``sim_server`` and
``agent_client`` beside each other, ``vacc`` on top, and nothing imports ``scripts``.

Every import counts, module-level or inside a function: a lazy import that dodges a
layer is still a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("protocol", "energy", "sim_server", "agent_client", "vacc", "scripts")
# What each package may import of the project's own (itself always).
ALLOWED = {
    "protocol": set(),
    "energy": {"protocol"},
    "sim_server": {"protocol", "energy"},
    "agent_client": {"protocol", "energy"},
    "vacc": {"protocol", "energy", "sim_server", "agent_client"},
}


def imported_packages(source: str) -> set[str]:
    """The project packages a module's source imports, anywhere in it."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        found.update(top for name in names if (top := name.partition(".")[0]) in PACKAGES)
    return found


def violations(package: str, files: list[Path]) -> list[str]:
    """``file: imports pkg`` for every import in ``files`` that crosses ``package``'s layer."""
    allowed = ALLOWED[package] | {package}
    return [f"{path.name}: imports {other}" for path in files for other in sorted(imported_packages(path.read_text()) - allowed)]


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_stays_in_its_layer(package: str) -> None:
    files = sorted((ROOT / package).rglob("*.py"))
    assert files, f"no modules found in {package}/"
    assert violations(package, files) == []


def test_the_check_sees_every_kind_of_import(tmp_path: Path) -> None:
    """The check can fail: module-level, from-, dotted and function-level imports all count."""
    bad = tmp_path / "bad.py"
    bad.write_text(
        "import sim_server.world\n"
        "from protocol import codec\n"
        "def f():\n"
        "    from vacc.evaluate import evaluate\n"
        "    import scripts.energy_frontier as ef\n"
        "from . import sibling\n"
    )
    assert imported_packages(bad.read_text()) == {"sim_server", "protocol", "vacc", "scripts"}
    assert violations("agent_client", [bad]) == ["bad.py: imports scripts", "bad.py: imports sim_server", "bad.py: imports vacc"]
    assert violations("vacc", [bad]) == ["bad.py: imports scripts"]
