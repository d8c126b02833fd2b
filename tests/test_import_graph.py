"""The import graph has no circle and no arrow back up: pure computation never imports
the edges (files, devices, MQTT, commands, plots), and nothing imports in a circle,
function-level (lazy) imports included."""

from __future__ import annotations

import ast
from pathlib import Path

PKG = "bladesonar"
#: modules of pure computation (no I/O) and the edges they must never import
PURE = ("bladesonar.waveform", "bladesonar.dsp", "bladesonar.sim", "bladesonar.analysis",
        "bladesonar.airflow_recording",
        "bladesonar.schema", "bladesonar.transitions", "bladesonar.live",
        "bladesonar.imaging", "bladesonar.reference_fit")
EDGES = ("bladesonar.io", "bladesonar.service", "bladesonar.commands", "bladesonar.plots",
         "bladesonar.loopback", "bladesonar.cli")


def _modules(root: Path) -> dict[str, Path]:
    out = {}
    for p in (root / PKG).rglob("*.py"):
        parts = p.relative_to(root).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = p
    return out


def _imports(name: str, path: Path, mods: dict[str, Path]) -> set[str]:
    """Every bladesonar module ``name`` imports, anywhere in its body."""
    is_pkg = path.name == "__init__.py"
    base = name.split(".") if is_pkg else name.split(".")[:-1]
    got = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                prefix = ".".join(base[:len(base) - node.level + 1])
                mod = f"{prefix}.{node.module}" if node.module else prefix
            else:
                mod = node.module or ""
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in mods else mod
                       for a in node.names]
        else:
            continue
        got |= {t for t in targets if t in mods and t != name}
    return got


def _graph(repo_root: Path) -> dict[str, set[str]]:
    mods = _modules(repo_root / "daemon")
    return {m: _imports(m, p, mods) for m, p in mods.items()}


def _in(name: str, group: tuple[str, ...]) -> bool:
    return any(name == g or name.startswith(g + ".") for g in group)


def test_pure_computation_never_imports_an_edge(repo_root):
    g = _graph(repo_root)
    bad = sorted((m, t) for m, ts in g.items() if _in(m, PURE) for t in ts if _in(t, EDGES))
    assert not bad, bad


def test_no_import_circles(repo_root):
    g = _graph(repo_root)
    # Tarjan's strongly connected components: any with more than one module is a circle
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    comps: list[list[str]] = []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in g[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            comps.append(comp)

    for v in sorted(g):
        if v not in index:
            visit(v)
    circles = [sorted(c) for c in comps if len(c) > 1]
    assert not circles, circles
