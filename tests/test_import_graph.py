"""The import graph has no circle and no arrow back up, function-level (lazy) imports
included. Every module belongs to one layer; a module imports only from its own layer or
lower ones, so pure computation never reaches a file, a device, MQTT or the command line,
and a new module must be given a layer here before the suite passes."""

from __future__ import annotations

import ast
from pathlib import Path

PKG = "bladesonar"
#: The layers, lowest first: (name, the modules and packages in it). ``bladesonar``
#: alone is the package's ``__init__`` (its version); a package name covers its modules.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("ground", ("bladesonar", "bladesonar.text", "bladesonar.errors", "bladesonar.schema",
                "bladesonar.blas", "bladesonar.answer")),
    ("settings", ("bladesonar.config", "bladesonar.config_doc")),
    ("computation", ("bladesonar.waveform", "bladesonar.dsp", "bladesonar.sim",
                     "bladesonar.imaging", "bladesonar.reference_fit",
                     "bladesonar.reference_build", "bladesonar.airflow_recording")),
    ("analysis", ("bladesonar.tuning", "bladesonar.transitions", "bladesonar.analyzer",
                  "bladesonar.offline", "bladesonar.live", "bladesonar.runtime_report",
                  "bladesonar.report_text")),
    ("io", ("bladesonar.io",)),
    ("edges", ("bladesonar.service", "bladesonar.plots", "bladesonar.loopback",
               "bladesonar.progress")),
    ("commands", ("bladesonar.commands",)),
    ("cli", ("bladesonar.cli", "bladesonar.__main__")),
)


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


def layer_of(name: str, layers=LAYERS) -> int | None:
    """Index of ``name``'s layer (the longest listed prefix that covers it), or None."""
    best: tuple[int, int] | None = None
    for i, (_, groups) in enumerate(layers):
        for g in groups:
            covers = name == g or (g != PKG and name.startswith(g + "."))
            if covers and (best is None or len(g) > best[1]):
                best = (i, len(g))
    return None if best is None else best[0]


def upward_imports(g: dict[str, set[str]], layers=LAYERS) -> list[str]:
    """Each import from a lower layer into a higher one, as 'a (layer) -> b (layer)'."""
    names = [n for n, _ in layers]
    bad = []
    for m, targets in sorted(g.items()):
        lm = layer_of(m, layers)
        for t in sorted(targets):
            lt = layer_of(t, layers)
            if lm is not None and lt is not None and lt > lm:
                bad.append(f"{m} ({names[lm]}) -> {t} ({names[lt]})")
    return bad


def circles(g: dict[str, set[str]]) -> list[list[str]]:
    """The import circles: Tarjan's strongly connected components of more than one
    module (iterative, so a deep graph cannot hit the recursion limit)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    comps: list[list[str]] = []
    for root in sorted(g):
        if root in index:
            continue
        work = [(root, iter(sorted(g[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(g.get(w, ())))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    x = stack.pop()
                    on.discard(x)
                    comp.append(x)
                    if x == v:
                        break
                if len(comp) > 1:
                    comps.append(sorted(comp))
    return comps


def test_every_module_has_a_layer(repo_root):
    missing = sorted(m for m in _graph(repo_root) if layer_of(m) is None)
    assert not missing, f"give these modules a layer in LAYERS: {missing}"


def test_no_import_runs_from_a_lower_layer_up(repo_root):
    bad = upward_imports(_graph(repo_root))
    assert not bad, bad


def test_no_import_circles(repo_root):
    found = circles(_graph(repo_root))
    assert not found, found


def test_the_checks_find_what_they_look_for():
    """The two checks on a small graph with one arrow back up and one circle."""
    layers = (("low", ("p.a", "p.b")), ("high", ("p.c",)))
    g = {"p.a": {"p.b"}, "p.b": {"p.a", "p.c"}, "p.c": {"p.a"}}
    assert upward_imports(g, layers) == ["p.b (low) -> p.c (high)"]
    assert circles(g) == [["p.a", "p.b", "p.c"]]
    assert circles({"p.a": {"p.b"}, "p.b": set(), "p.c": {"p.a", "p.b"}}) == []
    assert layer_of("p.d", layers) is None


def _tool_imports(path: Path) -> set[str]:
    """The bladesonar modules a Python tool imports (its AST; a tool's subprocess code in
    a string is not an import of the tool's)."""
    got = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            got |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            got |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
    return {m for m in got if m == PKG or m.startswith(PKG + ".")}


def test_no_tool_reaches_up_into_the_command_line(repo_root):
    """Tools use the package's lower modules (the BLAS setting is bladesonar.blas); one
    that wants a command runs it (``python -m bladesonar``), not cli.py's functions."""
    tools = [p for p in sorted((repo_root / "tools").iterdir()) if p.is_file() and (
        p.suffix == ".py" or p.read_bytes()[:64].split(b"\n")[0].endswith(b"python3"))]
    assert len(tools) >= 5
    bad = {p.name: sorted(m for m in _tool_imports(p)
                          if m in ("bladesonar.cli", "bladesonar.__main__"))
           for p in tools}
    assert not {k: v for k, v in bad.items() if v}, bad
    assert "bladesonar.cli" in _tool_imports_text("from bladesonar.cli import main\n")


def _tool_imports_text(code: str) -> set[str]:
    import tempfile
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as f:
        f.write(code)
    try:
        return _tool_imports(Path(f.name))
    finally:
        Path(f.name).unlink()
