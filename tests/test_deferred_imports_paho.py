"""service/deferred_imports.py is safe only for what paho-mqtt does with the modules it
defers: a stand-in ``ssl`` whose real module loads at the first attribute it lacks,
``urllib.request`` loaded on first use and ``hashlib`` without OpenSSL. This pins the
trick to the paho-mqtt it was checked against, from paho's own source: where each
deferred module is read (only on the TLS, proxy and websocket paths, which load the real
module), and which ``ssl`` exceptions its ``except`` clauses name (the stand-in must hold
each of them). A new paho-mqtt fails here until its source is checked again; one that
reads ``ssl`` on the plain-TCP path or catches another SSL error would break the trick.
tests/test_deferred_imports.py runs the trick against a real broker."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import paho.mqtt

from bladesonar.service.deferred_imports import DEFERRED, PLACEHOLDERS

#: The paho-mqtt whose source was checked (constraints.txt installs it).
PAHO_CHECKED = "2.2.0"
#: Where paho-mqtt 2.2.0 reads the deferred modules (``hashlib`` too: it loses OpenSSL),
#: outside ``except`` clauses and annotations: functions, dotted within their class. All
#: run only with TLS set up (tls_set, its socket wrap), a proxy (_get_proxy, which reads
#: urllib.request only with PySocks installed) or the websocket transport.
READS = {
    "ssl": {"Client.tls_set", "Client.tls_set_context", "Client._ssl_wrap_socket"},
    "urllib": {"Client._get_proxy"},
    "hashlib": {"_WebsocketWrapper._do_handshake"},
}
#: What the daemon itself catches from ``ssl`` on the same path.
OURS = Path(__file__).resolve().parents[1] / "daemon" / "bladesonar" / "service" / "publish.py"


class _Scan(ast.NodeVisitor):
    """Reads of the module names ``watch`` in one file: by enclosing function, and the
    ``ssl.X`` named in ``except`` clauses. Annotations are skipped when the file has
    ``from __future__ import annotations`` (then they are never evaluated)."""

    def __init__(self, watch: set[str], lazy_annotations: bool) -> None:
        self.watch, self.lazy = watch, lazy_annotations
        self.scope: list[str] = []
        self.reads: dict[str, set[str]] = {}
        self.caught: set[str] = set()

    def _where(self) -> str:
        return ".".join(self.scope) or "<module>"

    def _scoped(self, node: ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef) -> None:
        for d in node.decorator_list:
            self.visit(d)
        if not isinstance(node, ast.ClassDef):
            args = node.args
            for default in [*args.defaults, *args.kw_defaults]:
                if default is not None:
                    self.visit(default)
            if not self.lazy:
                for a in [*args.posonlyargs, *args.args, *args.kwonlyargs, args.vararg,
                          args.kwarg]:
                    if a is not None and a.annotation is not None:
                        self.visit(a.annotation)
                if node.returns is not None:
                    self.visit(node.returns)
        else:
            for b in [*node.bases, *node.keywords]:
                self.visit(b)
        self.scope.append(node.name)
        for stmt in node.body:
            self.visit(stmt)
        self.scope.pop()

    visit_FunctionDef = visit_AsyncFunctionDef = visit_ClassDef = _scoped

    def visit_AnnAssign(self, node: ast.AnnAssign) -> None:
        if not self.lazy:
            self.visit(node.annotation)
        if node.value is not None:
            self.visit(node.value)
        self.visit(node.target)

    def visit_ExceptHandler(self, node: ast.ExceptHandler) -> None:
        if node.type is not None:
            for n in ast.walk(node.type):
                if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) \
                        and n.value.id == "ssl":
                    self.caught.add(n.attr)
                elif isinstance(n, ast.Name) and n.id in self.watch and n.id != "ssl":
                    self.reads.setdefault(n.id, set()).add(self._where())
        for stmt in node.body:
            self.visit(stmt)

    def visit_Name(self, node: ast.Name) -> None:
        if node.id in self.watch and isinstance(node.ctx, ast.Load):
            self.reads.setdefault(node.id, set()).add(self._where())

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        top = (node.module or "").split(".")[0]
        if top in self.watch and node.module != "urllib.parse":
            self.reads.setdefault(top, set()).add(self._where())


def _scan(path: Path, watch: set[str]) -> _Scan:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    lazy = any(isinstance(n, ast.ImportFrom) and n.module == "__future__"
               and any(a.name == "annotations" for a in n.names) for n in tree.body)
    s = _Scan(watch, lazy)
    s.visit(tree)
    return s


def _paho() -> list[Path]:
    return sorted(Path(paho.mqtt.__file__).parent.glob("*.py"))


def test_the_installed_paho_is_the_one_the_trick_was_checked_against(repo_root):
    pinned = re.search(r"^paho-mqtt==(\S+)$",
                       (Path(repo_root) / "constraints.txt").read_text(), re.M)
    assert pinned and pinned.group(1) == PAHO_CHECKED, "constraints.txt installs another paho"
    assert paho.mqtt.__version__ == PAHO_CHECKED, (
        f"paho-mqtt {paho.mqtt.__version__} is installed, service/deferred_imports.py "
        f"was checked against {PAHO_CHECKED}: check where the new one reads ssl, urllib "
        "and hashlib (this file's tests) and set PAHO_CHECKED")


def test_paho_reads_the_deferred_modules_only_on_the_tls_proxy_and_websocket_paths():
    assert {d.split(".")[0] for d in DEFERRED} | {"hashlib"} == set(READS)
    reads: dict[str, set[str]] = {m: set() for m in READS}
    for f in _paho():
        for mod, where in _scan(f, set(READS)).reads.items():
            reads[mod] |= where
    assert reads == READS


def test_every_ssl_error_paho_and_the_publisher_catch_is_a_placeholder():
    caught: set[str] = set()
    for f in [*_paho(), OURS]:
        caught |= _scan(f, {"ssl"}).caught
    assert caught, "no except clause names an ssl error: is the scan still right?"
    assert caught <= set(PLACEHOLDERS["ssl"]), caught - set(PLACEHOLDERS["ssl"])


def test_the_scan_finds_reads_outside_except_clauses_and_annotations(tmp_path):
    """The scan on a small file: a read at import time and one in a plain-TCP method are
    found, an annotation and an except clause are not reads."""
    f = tmp_path / "m.py"
    f.write_text("from __future__ import annotations\nimport ssl\nX = ssl.PROTOCOL_TLS\n"
                 "class C:\n    def recv(self, s: ssl.SSLSocket) -> ssl.SSLSocket:\n"
                 "        ctx: ssl.SSLContext | None = None\n        try:\n"
                 "            return s\n        except ssl.SSLZeroReturnError:\n"
                 "            return ssl.RAND_status()\n")
    s = _scan(f, {"ssl"})
    assert s.reads == {"ssl": {"<module>", "C.recv"}}
    assert s.caught == {"SSLZeroReturnError"}
