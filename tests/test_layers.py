"""The layering holds: no module imports a module of a higher layer, and no module imports itself
back through others (no import cycle). Every import counts, those inside functions included.

The layers are those of ``docs/design.md``; a module's layer is that of the first prefix of its
dotted name found in ``LAYERS``. Imports of the package root (``l3gs_opt`` itself, for the public
API) are allowed only from the CLI and the tests.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Where each package's source lives (setuptools' package-dir in pyproject.toml).
SOURCES = {"l3gs_opt": ROOT / "l3gs_opt", "l3gs_opt.models": ROOT / "models",
           "l3gs_opt.solvers": ROOT / "solvers", "l3gs_opt.renderer": ROOT / "renderer"}
#: Rank of each package or module: a module may import its own rank or lower ones only.
LAYERS = {
    "l3gs_opt.errors": 0, "l3gs_opt.checks": 0, "l3gs_opt.input_files": 0, "l3gs_opt.jsonout": 0,
    "l3gs_opt.output_files": 0,
    "l3gs_opt.records": 0,
    "l3gs_opt.executors": 0, "l3gs_opt.stop": 0,
    "l3gs_opt.data": 0,
    "l3gs_opt.problem": 1, "l3gs_opt.scene": 1, "l3gs_opt.traces": 1,
    "l3gs_opt.models": 2, "l3gs_opt.solvers": 2, "l3gs_opt.renderer": 2,
    "l3gs_opt.methods": 3, "l3gs_opt.pipeline": 3,
    "l3gs_opt.simulator": 4,
    "l3gs_opt.bench": 5, "l3gs_opt.experiments": 5, "l3gs_opt.delivery": 5,
    "l3gs_opt.cli": 6,
    "l3gs_opt": 7,
}


def _modules() -> dict[str, Path]:
    out = {}
    for package, folder in SOURCES.items():
        for path in folder.rglob("*.py"):
            parts = [p for p in path.relative_to(folder).with_suffix("").parts if p != "__init__"]
            out[".".join([package, *parts])] = path
    return out


MODULES = _modules()


def _is_package(name: str) -> bool:
    return MODULES[name].name == "__init__.py"


def _imports(name: str) -> set[str]:
    """Every l3gs_opt module ``name`` imports (resolved to a module of MODULES where possible)."""
    tree = ast.parse(MODULES[name].read_text(encoding="utf-8"))
    here = name if _is_package(name) else name.rsplit(".", 1)[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here.split(".")
                base = base[:len(base) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            targets = [f"{module}.{a.name}" for a in node.names] + [module]
        else:
            continue
        for target in targets:
            if not target.startswith("l3gs_opt"):
                continue
            # the longest prefix that is a module of ours
            parts = target.split(".")
            while parts and ".".join(parts) not in MODULES:
                parts.pop()
            if parts:
                found.add(".".join(parts))
    found.discard(name)
    return found


def _rank(name: str) -> int:
    parts = name.split(".")
    while parts:
        key = ".".join(parts)
        if key in LAYERS:
            return LAYERS[key]
        parts.pop()
    raise KeyError(name)


def test_every_module_has_a_layer():
    missing = [m for m in MODULES if m != "l3gs_opt" and _rank(m) == LAYERS["l3gs_opt"]]
    assert missing == [], f"modules at the package root with no layer: {missing}"


def test_no_import_from_a_higher_layer():
    bad = []
    for name in MODULES:
        for target in _imports(name):
            if target == "l3gs_opt" and _rank(name) >= LAYERS["l3gs_opt.cli"]:
                continue
            # a package's own __init__ may import its members
            if _is_package(target) and name.startswith(target + "."):
                continue
            if _rank(target) > _rank(name):
                bad.append(f"{name} (layer {_rank(name)}) imports {target} (layer {_rank(target)})")
    assert bad == [], "\n".join(bad)


def test_no_import_cycles():
    graph = {name: {t for t in _imports(name) if not (_is_package(t) and name.startswith(t + "."))}
             for name in MODULES}
    # package __init__s that only re-export their members are not part of a cycle through them
    state: dict[str, int] = {}
    cycles: list[list[str]] = []

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [])
    assert cycles == [], "\n".join(" -> ".join(c) for c in cycles[:10])


def test_the_checker_sees_a_violation(tmp_path, monkeypatch):
    """The parser finds imports inside functions and relative ones: a planted upward import fails."""
    fake = tmp_path / "fake.py"
    fake.write_text("def f():\n    from ..cli.main import main\n    from l3gs_opt.simulator import simulation\n")
    monkeypatch.setitem(MODULES, "l3gs_opt.problem.fake", fake)
    found = _imports("l3gs_opt.problem.fake")
    assert {"l3gs_opt.cli.main", "l3gs_opt.simulator.simulation"} <= found
    with pytest.raises(AssertionError, match="imports l3gs_opt.cli.main"):
        test_no_import_from_a_higher_layer()
