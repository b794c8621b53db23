"""Dependencies point downward (DESIGN.md): the core imports none of the I/O stacks, and no module imports itself back.

Two checks that keep the layering mends from quietly coming undone:
- each core module, imported alone in a fresh interpreter, loads none of pymavlink, PyAV, ZeroMQ, torch or aiohttp
  (they belong to mavlink/, video/, perception/ and dashboard/, which sit above it);
- the import graph of viva_sitl/ (read with `ast`, lazy imports inside functions counted, imports under
  `if TYPE_CHECKING:` not) has no circles between files.
"""

from __future__ import annotations

import ast
import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "viva_sitl"
HEAVY = ("pymavlink", "av", "zmq", "torch", "aiohttp")
# The core: what every trial worker and gym env imports (the vehicle takes its super-resolution hook from the
# caller, so it imports nothing of perception/), and the episode every trial and gym env runs.
CORE = (
    "viva_sitl.config",
    "viva_sitl.dynamics",
    "viva_sitl.camera",
    "viva_sitl.footage",
    "viva_sitl.world",
    "viva_sitl.autopilot",
    "viva_sitl.sim",
    "viva_sitl.vehicle",
    "viva_sitl.evaluation.episode",
)

_PROBE = """
import json, sys, time
t = time.perf_counter()
import {module}
dt = time.perf_counter() - t
print(json.dumps({{"s": dt, "heavy": sorted({{m.split(".")[0] for m in sys.modules}} & set({heavy!r}))}}))
"""


def _import_alone(module: str) -> dict[str, object]:
    out = subprocess.run(
        [sys.executable, "-c", _PROBE.format(module=module, heavy=HEAVY)],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    result: dict[str, object] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


@pytest.mark.parametrize("module", CORE)
def test_core_module_loads_no_io_stack(module: str) -> None:
    got = _import_alone(module)
    print(f"import {module}: {got['s']:.3f} s")  # type: ignore[str-format]
    assert got["heavy"] == [], f"import {module} loaded {got['heavy']}: a core module reaches an upper layer"


@pytest.mark.parametrize("face", ["viva_sitl.mavlink", "viva_sitl.video", "viva_sitl.perception"])
def test_lazy_package_faces_resolve_every_name(face: str) -> None:
    """The faces that load their parts on first use still give every name they list, and refuse unknown ones."""
    module = importlib.import_module(face)
    for name in module.__all__:
        assert getattr(module, name) is not None, f"{face}.{name}"
    with pytest.raises(AttributeError, match="no_such_name"):
        module.no_such_name  # noqa: B018


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imported(tree: ast.Module, module: str, is_package: bool, known: set[str]) -> set[str]:
    """The viva_sitl modules (files) this module imports, anywhere in its body except under `if TYPE_CHECKING:`.

    `from pkg import name` counts as an import of pkg.name when that is a module, else of pkg (its __init__)."""
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("viva_sitl"):
                    found.add(alias.name)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = module.split(".") if is_package else module.split(".")[:-1]
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            if base.startswith("viva_sitl"):
                for alias in node.names:
                    sub = f"{base}.{alias.name}"
                    found.add(sub if sub in known else base)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    # Importing viva_sitl.a.b also runs viva_sitl/a/__init__.py: an edge to that package face, unless this file lies
    # inside package a itself (its own packages are already being imported when it runs).
    own = {".".join(module.split(".")[:i]) for i in range(1, module.count(".") + 2)}
    faces = {".".join(m.split(".")[:i]) for m in found for i in range(2, m.count(".") + 1)}
    return {m for m in found | (faces - own) if m in known and m != module}


def _import_graph() -> dict[str, set[str]]:
    files = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    known = set(files)
    return {
        name: _imported(ast.parse(path.read_text(encoding="utf-8")), name, path.name == "__init__.py", known)
        for name, path in files.items()
    }


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0

    def strong(v: str) -> None:
        nonlocal counter
        index[v] = low[v] = counter
        counter += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for v in sorted(graph):
        if v not in index:
            strong(v)
    return sorted(out)


def test_import_graph_has_no_circles() -> None:
    graph = _import_graph()
    assert len(graph) > 100 and "viva_sitl.config" in graph  # the walk found the package
    circles = _circles(graph)
    assert circles == [], "import circles between files (lazy imports count): " + "; ".join(
        " <-> ".join(c) for c in circles
    )


def test_circle_finder_sees_a_lazy_circle() -> None:
    """The check itself can fail: a lazy import inside a function closes a circle; one under TYPE_CHECKING does not."""
    a = ast.parse("from viva_sitl.b import f\n")
    b = ast.parse("def g():\n    from viva_sitl.a import h\n")
    c = ast.parse("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from viva_sitl.a import h\n")
    known = {"viva_sitl.a", "viva_sitl.b", "viva_sitl.c"}
    graph = {
        "viva_sitl.a": _imported(a, "viva_sitl.a", False, known),
        "viva_sitl.b": _imported(b, "viva_sitl.b", False, known),
        "viva_sitl.c": _imported(c, "viva_sitl.c", False, known),
    }
    assert _circles(graph) == [["viva_sitl.a", "viva_sitl.b"]]
    graph["viva_sitl.a"] = {"viva_sitl.c"}
    graph["viva_sitl.b"] = set()
    assert _circles(graph) == []


def test_vehicle_does_not_import_perception() -> None:
    """sim.py's promise: the core never imports the perception code (the SR hook is handed in by the caller); only
    the leaf `[perception.sr]` config table (perception.config, its errors) that config.py parses."""
    out = subprocess.run(
        [sys.executable, "-c", "import sys, viva_sitl.vehicle; print(sorted(m for m in sys.modules if 'perception' in m))"],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    leaf = ["viva_sitl.perception", "viva_sitl.perception.config", "viva_sitl.perception.errors"]
    assert set(eval(out.stdout)) <= set(leaf), out.stdout  # noqa: S307 - our own probe's list literal
