"""No import cycles inside the package, checked on the source.

The graph is built with :mod:`ast` from every module of ``tof_fpn_torch``:

- every ``import`` and ``from ... import`` counts, at module level and inside functions alike (a
  late import inside a function that only dodges a circle is still a circle);
- relative imports are resolved; ``from pkg import name`` is an edge to the submodule
  ``pkg.name`` when that is a module, else to ``pkg`` (its ``__init__``);
- importing ``a.b.c`` is an edge to ``a.b.c`` only: the import of its parent packages that Python
  does on the way is not counted (every module would otherwise sit in a circle with the
  ``__init__`` of its package that re-exports it);
- ``importlib.import_module`` with a computed name (the package's lazy ``__getattr__``, the
  command registry) is not an edge; with a literal name it is;
- an import under ``if TYPE_CHECKING:`` is not an edge: it never runs (the package's index
  imports its lazy names there for type checkers).

A cycle is a strongly connected component of more than one module, or a module importing itself;
each is reported as chains ``a -> b -> c -> a`` (a shortest circle through every module of it)
with the file and line of every import on the way.
"""

from __future__ import annotations

import ast
from collections import deque
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "tof_fpn_torch"


def module_names(root: Path) -> dict[str, Path]:
    """Dotted name -> file of every module of the package at ``root`` (a package's name is
    that of its ``__init__.py``)."""
    out: dict[str, Path] = {}
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(root.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _resolve_relative(module: str, is_package: bool, level: int, target: str | None) -> str:
    """The absolute name of ``from <level dots><target> import ...`` written in ``module``."""
    base = module.split(".") if is_package else module.split(".")[:-1]
    if level > 1:
        base = base[: len(base) - (level - 1)]
    return ".".join([*base, *([target] if target else [])])


def _known(name: str, modules: dict[str, Path]) -> str | None:
    """``name`` if it is a module of the package, else its longest prefix that is (None when
    it is outside the package)."""
    parts = name.split(".")
    while parts:
        candidate = ".".join(parts)
        if candidate in modules:
            return candidate
        parts.pop()
    return None


def _literal_import_module(node: ast.Call) -> tuple[str, str | None] | None:
    """``(name, package)`` of ``importlib.import_module("literal"[, package])``; None for any
    other call and for a computed name."""
    f = node.func
    called = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
    if called != "import_module" or not node.args:
        return None
    name = node.args[0]
    if not (isinstance(name, ast.Constant) and isinstance(name.value, str)):
        return None
    pkg = node.args[1] if len(node.args) > 1 else None
    pkg = next((k.value for k in node.keywords if k.arg == "package"), pkg)
    if isinstance(pkg, ast.Constant) and isinstance(pkg.value, str):
        return name.value, pkg.value
    return name.value, "__name__" if isinstance(pkg, ast.Name) else None


def _type_checking_only(tree: ast.AST) -> set[int]:
    """``id`` of every node under ``if TYPE_CHECKING:`` / ``if typing.TYPE_CHECKING:``."""
    out: set[int] = set()
    for node in ast.walk(tree):
        test = node.test if isinstance(node, ast.If) else None
        name = test.id if isinstance(test, ast.Name) else getattr(test, "attr", None)
        if name == "TYPE_CHECKING":
            out |= {id(n) for child in node.body for n in ast.walk(child)}
    return out


def import_edges(modules: dict[str, Path]) -> dict[str, dict[str, int]]:
    """Module -> {imported module of the package: line of the first such import}."""
    graph: dict[str, dict[str, int]] = {m: {} for m in modules}
    for mod, path in modules.items():
        is_pkg = path.name == "__init__.py"
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        never_run = _type_checking_only(tree)
        for node in ast.walk(tree):
            if id(node) in never_run:
                continue
            targets: list[str | None] = []
            if isinstance(node, ast.Import):
                targets = [_known(a.name, modules) for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = _resolve_relative(mod, is_pkg, node.level, node.module)
                for a in node.names:
                    sub = f"{base}.{a.name}"
                    targets.append(sub if sub in modules else _known(base, modules))
            elif isinstance(node, ast.Call):
                lit = _literal_import_module(node)
                if lit is not None:
                    name, pkg = lit
                    if name.startswith("."):
                        anchor = mod if pkg == "__name__" else (pkg or mod)
                        level = len(name) - len(name.lstrip("."))
                        name = _resolve_relative(anchor, True, level, name.lstrip(".") or None)
                    targets = [_known(name, modules)]
            for t in targets:
                if t is not None:
                    graph[mod].setdefault(t, node.lineno)
    return graph


def strongly_connected(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """Tarjan's strongly connected components (iterative), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, it = work[-1]
            nxt = next(it, None)
            if nxt is not None:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter
                    counter += 1
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph[nxt]))))
                elif nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == node:
                        break
                out.append(sorted(comp))
    return out


def _shortest_circle(graph: dict[str, dict[str, int]], comp: set[str], start: str) -> list[str]:
    """The shortest path ``start -> ... -> start`` inside ``comp`` (breadth first)."""
    prev: dict[str, str] = {}
    queue = deque([start])
    while queue:
        node = queue.popleft()
        for nxt in sorted(graph[node]):
            if nxt not in comp:
                continue
            if nxt == start:
                path = [node]
                while path[-1] != start:
                    path.append(prev[path[-1]])
                return [*reversed(path), start]
            if nxt not in prev:
                prev[nxt] = node
                queue.append(nxt)
    raise AssertionError(f"{start} is in no circle of {sorted(comp)}")


def import_cycles(graph: dict[str, dict[str, int]]) -> list[list[list[str]]]:
    """Every cycle: per strongly connected component of more than one module (or a module that
    imports itself), circles covering all its modules, each ``[a, b, ..., a]``."""
    out = []
    for comp in strongly_connected(graph):
        if len(comp) == 1 and comp[0] not in graph[comp[0]]:
            continue
        members, circles, covered = set(comp), [], set()
        for m in comp:
            if m not in covered:
                circle = _shortest_circle(graph, members, m)
                circles.append(circle)
                covered.update(circle)
        out.append(circles)
    return out


def describe(graph: dict[str, dict[str, int]], modules: dict[str, Path], cycles) -> str:
    """The cycles as readable chains, with where each import is written."""
    root = PACKAGE.parent
    lines = []
    for circles in cycles:
        members = sorted({m for c in circles for m in c})
        lines.append(f"cycle of {len(members)} module(s): {', '.join(members)}")
        for circle in circles:
            lines.append("  " + " -> ".join(circle))
            for a, b in zip(circle[:-1], circle[1:], strict=True):
                path = modules[a]
                where = path.relative_to(root) if path.is_relative_to(root) else path
                lines.append(f"      {where}:{graph[a][b]} imports {b}")
    return "\n".join(lines)


def test_the_package_has_no_import_cycle():
    modules = module_names(PACKAGE)
    graph = import_edges(modules)
    cycles = import_cycles(graph)
    assert not cycles, "import cycles in the package:\n" + describe(graph, modules, cycles)


def _write(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")


def test_the_graph_sees_the_cycles_of_a_fake_package(tmp_path):
    """A package with known edges: a late import inside a function closing a circle, a
    ``from . import module``, a self-import, a literal ``import_module``; and what is not a
    circle: a subpackage's ``__init__`` re-exporting its module (the module's implicit import
    of its parent is not an edge), ``from pkg import name`` of a name defined in ``__init__``,
    a computed ``import_module``, an import under ``if TYPE_CHECKING:``, imports from outside
    the package."""
    _write(
        tmp_path,
        {
            "fake/__init__.py": (
                "import importlib\n"
                "from typing import TYPE_CHECKING\n"
                "VERSION = 1\n"
                "if TYPE_CHECKING:  # never run: no edge (sub.d reads VERSION back)\n"
                "    from . import sub as sub\n"
                "def __getattr__(name):\n"
                "    return importlib.import_module(f'.{name}', __name__)\n"
            ),
            # a -> b -> c -> a, the last edge a late import
            "fake/a.py": "import os\nfrom . import b\n",
            "fake/b.py": "def f():\n    from .c import g\n    return g\n",
            "fake/c.py": "from fake.a import x as y\ng = 1\n",
            # the subpackage re-exports its module d (d's implicit import of sub/__init__ is no
            # edge back), d reads a name of the top package's __init__, e a name of sub's
            "fake/sub/__init__.py": "from .d import D\n",
            "fake/sub/d.py": "from .. import VERSION\nclass D: ...\n",
            "fake/sub/e.py": "from ..sub import D\nimport fake.sub.d\n",
            "fake/sub/f.py": "from . import f\n",  # a self-loop
            # literal import_module: h -> i -> h; computed: no edge
            "fake/h.py": "import importlib\nM = importlib.import_module('.i', 'fake')\n",
            "fake/i.py": (
                "import importlib\n"
                "from . import h\n"
                "def load(n):\n"
                "    return importlib.import_module(f'fake.{n}')\n"
            ),
        },
    )
    modules = module_names(tmp_path / "fake")
    assert set(modules) == {
        "fake",
        "fake.a",
        "fake.b",
        "fake.c",
        "fake.sub",
        "fake.sub.d",
        "fake.sub.e",
        "fake.sub.f",
        "fake.h",
        "fake.i",
    }
    graph = import_edges(modules)
    assert {m: set(e) for m, e in graph.items()} == {
        "fake": set(),
        "fake.a": {"fake.b"},
        "fake.b": {"fake.c"},
        "fake.c": {"fake.a"},
        "fake.sub": {"fake.sub.d"},
        "fake.sub.d": {"fake"},
        "fake.sub.e": {"fake.sub", "fake.sub.d"},
        "fake.sub.f": {"fake.sub.f"},
        "fake.h": {"fake.i"},
        "fake.i": {"fake.h"},
    }
    assert graph["fake.b"]["fake.c"] == 2  # the late import, line 2
    cycles = import_cycles(graph)
    assert sorted(cycles) == [
        [["fake.a", "fake.b", "fake.c", "fake.a"]],
        [["fake.h", "fake.i", "fake.h"]],
        [["fake.sub.f", "fake.sub.f"]],
    ]
    text = describe(graph, modules, cycles)
    assert "fake.a -> fake.b -> fake.c -> fake.a" in text
    assert "fake/b.py:2 imports fake.c" in text.replace("\\", "/")


def test_the_cycles_cover_every_module_of_a_component():
    """Two circles sharing a module (a -> b -> a, c -> a -> c): one component, both circles."""
    graph = {"a": {"b": 1, "c": 2}, "b": {"a": 1}, "c": {"a": 1}, "d": {"a": 1}}
    assert import_cycles(graph) == [[["a", "b", "a"], ["c", "a", "c"]]]
    assert strongly_connected({"x": {}}) == [["x"]] and import_cycles({"x": {}}) == []


def _reach(graph: dict[str, dict[str, int]], start: str) -> set[str]:
    seen, todo = set(), [start]
    while todo:
        for nxt in graph[todo.pop()]:
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def test_the_diagnosis_model_needs_only_the_term_base():
    """The model receives its terms: it and the prediction reach no term module but
    ``terms/base.py`` (and the package's ``__init__``) and not the catalogue; no term reaches
    the model or the catalogue."""
    graph = import_edges(module_names(PACKAGE))
    diag = "tof_fpn_torch.diagnosis"
    terms = {m for m in graph if m.startswith(f"{diag}.terms")}
    assert len(terms) > 20
    for top in (f"{diag}.model", f"{diag}.prediction"):
        reached = _reach(graph, top)
        assert reached & terms <= {f"{diag}.terms", f"{diag}.terms.base"}, top
        assert f"{diag}.catalogue" not in reached, top
    for t in sorted(terms):
        assert not {f"{diag}.model", f"{diag}.catalogue"} & _reach(graph, t), t
