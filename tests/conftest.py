"""Test tiers, applied automatically: ``unit``, ``integration`` and ``slow``.

* ``integration``: a test under ``tests/integration/``, or one that starts processes: its
  own code, a module function it calls (transitively) or a fixture it uses names a
  launcher, ``subprocess``, Ray or multiprocessing. An explicit
  ``@pytest.mark.integration`` also counts.
* ``unit``: every other test. It runs in-process; a unit test that spawns a Python
  process anyway fails with a line saying to mark it ``integration``, so the tier
  cannot drift.
* ``slow``: marked by hand (``@pytest.mark.slow``) on tests that take over ~10 s alone.

``make test-fast`` runs ``unit and not slow``; ``make test`` runs everything.
"""

from __future__ import annotations

import ast
import functools
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from proctools import ProcessSpawnedInUnitTest

TESTS = Path(__file__).resolve().parent
# The suite's workers share the cores: one torch (and BLAS) thread per process, else their
# spin-waiting threads take turns on the same cores and a training runs about twice as slow.
# Set before any test imports torch; spawned servers, clients and trainers inherit it.
os.environ.setdefault("OMP_NUM_THREADS", "1")
# What starts processes: the launchers, the stdlib's and Ray's process APIs, and the project's
# entry points that spawn servers or actors (the trainers, the env, the CLI runner).
PROCESS_WORDS = re.compile(
    r"\b(local_server|start_server|spawn_server|subprocess|Popen|ray|multiprocessing|run_vacc"
    r"|train|train_distributed|StreamActor|CliRunner|VisionACCEnv|gym\.make)\b"
)


@functools.cache
def _module_spawners(path: str) -> frozenset[str]:
    """Names of the functions in a module that start processes: directly, through another
    function of the module, or through a helper imported from a module under tests/."""
    try:
        source = Path(path).read_text()
        tree = ast.parse(source)
    except (OSError, SyntaxError, ValueError):
        return frozenset()
    spawners = set(_imported_spawners(tree))
    calls: dict[str, set[str]] = {}
    lines = source.splitlines()
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            # the function's whole lines (ast.get_source_segment re-reads the source per call)
            if PROCESS_WORDS.search("\n".join(lines[node.lineno - 1 : node.end_lineno])):
                spawners.add(node.name)
            calls.setdefault(node.name, set()).update(n.id for n in ast.walk(node) if isinstance(n, ast.Name))
    changed = True
    while changed:  # a fixed point over the module's own call graph
        changed = False
        for name, used in calls.items():
            if name not in spawners and used & spawners:
                spawners.add(name)
                changed = True
    return frozenset(spawners)


@functools.cache
def _helper_modules() -> dict[str, list[Path]]:
    """The Python files under tests/ by module name (a test imports a helper by its stem)."""
    found: dict[str, list[Path]] = {}
    for path in TESTS.rglob("*.py"):
        found.setdefault(path.stem, []).append(path)
    return found


@functools.cache
def _ours(filename: str) -> bool:
    return TESTS in Path(filename).parents


def _imported_spawners(tree: ast.Module) -> set[str]:
    """The names a module imports from helper modules under tests/ that start processes."""
    found: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for helper in _helper_modules().get(node.module, ()):
                found.update(alias.asname or alias.name for alias in node.names if alias.name in _module_spawners(str(helper)))
    return found


def _starts_processes(func: object) -> bool:
    """Whether a test or fixture of ours starts processes (pytest's own fixtures never do)."""
    code = getattr(func, "__code__", None)
    if code is None or func is _unit_tests_stay_in_process.__wrapped__ or not _ours(code.co_filename):  # type: ignore[attr-defined]
        return False
    return func.__name__ in _module_spawners(code.co_filename)  # type: ignore[attr-defined]


def _is_integration(item: pytest.Item) -> bool:
    if item.get_closest_marker("integration") or _ours(str(item.path)) and Path(item.path).parts[len(TESTS.parts)] == "integration":
        return True
    if not isinstance(item, pytest.Function):
        return False
    if _starts_processes(item.function):
        return True
    defs = item._fixtureinfo.name2fixturedefs  # the fixtures this test uses, transitively
    return any(_starts_processes(d.func) for name in item.fixturenames for d in defs.get(name, ()))


@pytest.hookimpl(tryfirst=True)  # before -m selects on the marks
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        item.add_marker(pytest.mark.integration if _is_integration(item) else pytest.mark.unit)
    # The modules that start processes or hold slow tests run first, the quick in-process ones
    # last: the workers then finish together instead of one running a long test alone at the end.
    heavy = {item.module for item in items if item.get_closest_marker("integration") or item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.module not in heavy)


@pytest.fixture(autouse=True)
def _unit_tests_stay_in_process(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    """A unit test that starts a Python process (a server, the CLI) is mislabelled: fail it."""
    if request.node.get_closest_marker("integration"):
        return
    popen = subprocess.Popen

    class GuardedPopen(popen):  # type: ignore[misc, valid-type]
        def __init__(self, args, *rest, **kw):  # noqa: ANN001
            argv = [args] if isinstance(args, str | bytes) else list(args)
            if argv and str(argv[0]) == sys.executable:
                raise ProcessSpawnedInUnitTest(f"{request.node.nodeid} starts a Python process: mark it @pytest.mark.integration")
            super().__init__(args, *rest, **kw)

    monkeypatch.setattr(subprocess, "Popen", GuardedPopen)
