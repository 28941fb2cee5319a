"""MkDocs hook: the API reference and the command-line reference, generated at every build.

Nothing here is written by hand per module: the package is walked, so a module that is added,
moved or removed (and a name that moves between modules) changes the reference by itself.

* **Public modules**: every module of ``tof_fpn_torch`` with no dotted component starting with
  ``_`` (``__main__`` left out).
* **Public names of a module**: its ``__all__``; a module without ``__all__``: the names its own
  source defines at top level (``def``, ``class``, assignment) that do not start with ``_``.
* **Where a name is documented (its home)**: a name is exported by several modules (the package
  re-exports what its modules define). It is rendered once, in the public module whose source
  defines it (``def`` / ``class`` before assignment); when it is defined in a private module, in
  the exporting public module nearest to that module. Every module's section lists all its public
  names, each linked to its home.
* **Pages**: one page per top-level subpackage or module (``reference/<name>.md``): its
  docstring, then a section per public module: docstring, the table of its public names, and the
  names whose home it is. ``cli.md``: every ``tof-fpn`` command's ``--help``.

``tests/test_docs_reference.py`` builds the site and checks every public name against the
site's ``objects.inv``, independently of the home chosen here.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import importlib
import inspect
import os
import pkgutil
import re
from functools import cache
from types import ModuleType

PACKAGE = "tof_fpn_torch"
REFERENCE_DIR = "reference"
NAV_TITLE = "API reference"
CLI_PAGE = "cli.md"
CLI_NAV_TITLE = "Command line"

_ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|attr|data|exc|obj|const):`~?([^`]+)`")


def is_public_module(name: str) -> bool:
    parts = name.split(".")
    return parts[0] == PACKAGE and not any(p.startswith("_") for p in parts[1:])


@cache
def public_modules() -> tuple[str, ...]:
    """Dotted names of the public modules, sorted (the package first)."""
    pkg = importlib.import_module(PACKAGE)
    found = {PACKAGE}
    for info in pkgutil.walk_packages(pkg.__path__, prefix=PACKAGE + ".", onerror=_raise):
        if is_public_module(info.name):
            found.add(info.name)
    return tuple(sorted(found, key=lambda n: (n != PACKAGE, n)))


def _raise(name: str) -> None:
    raise ImportError(f"cannot import {name} while walking {PACKAGE}")


@cache
def module(name: str) -> ModuleType:
    return importlib.import_module(name)


@cache
def defined_names(name: str) -> dict[str, int]:
    """Top-level names the module's own source defines: 2 for def / class, 1 for assignment."""
    try:
        source = inspect.getsource(module(name))
    except (OSError, TypeError):
        return {}
    found: dict[str, int] = {}
    for node in ast.parse(source).body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            found[node.name] = 2
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                for sub in ast.walk(target):
                    if isinstance(sub, ast.Name):
                        found.setdefault(sub.id, 1)
    return found


@cache
def public_names(name: str) -> tuple[str, ...]:
    """The module's ``__all__``, or the public names its source defines."""
    mod = module(name)
    if hasattr(mod, "__all__"):
        return tuple(mod.__all__)
    return tuple(n for n in defined_names(name) if not n.startswith("_"))


def exporters(obj: object, name: str) -> list[str]:
    """Public modules listing ``name`` as a public name bound to this very object."""
    return [
        m
        for m in public_modules()
        if name in public_names(m) and getattr(module(m), name, _MISSING) is obj
    ]


_MISSING = object()


@cache
def _homes() -> dict[tuple[str, str], str]:
    """(module, name) -> the module whose section renders the object."""
    homes: dict[tuple[str, str], str] = {}
    for mod_name in public_modules():
        for name in public_names(mod_name):
            obj = getattr(module(mod_name), name)
            if inspect.ismodule(obj):
                continue
            candidates = exporters(obj, name) or [mod_name]
            defining = [m for m in candidates if defined_names(m).get(name)]
            if defining:
                best = max(defining, key=lambda m: (defined_names(m)[name], len(m)))
            else:
                origin = getattr(obj, "__module__", None) or ""
                best = max(candidates, key=lambda m: (_common_prefix(m, origin), len(m)))
            homes[(mod_name, name)] = best
    return homes


def _common_prefix(a: str, b: str) -> int:
    n = 0
    for x, y in zip(a.split("."), b.split("."), strict=False):
        if x != y:
            break
        n += 1
    return n


def home(mod_name: str, name: str) -> str:
    """The reference id of ``mod_name.name``: ``<home module>.<name>``, or a module's name."""
    obj = getattr(module(mod_name), name)
    if inspect.ismodule(obj):
        return obj.__name__
    return f"{_homes()[(mod_name, name)]}.{name}"


def page_of(mod_name: str) -> str:
    """The page (relative to the docs) documenting a public module."""
    top = ".".join(mod_name.split(".")[:2])
    return f"{REFERENCE_DIR}/{top}.md"


def summary(obj: object) -> str:
    """First sentence of a class', function's or module's docstring, for a table cell."""
    if not (inspect.ismodule(obj) or inspect.isclass(obj) or callable(obj)):
        return ""
    doc = inspect.getdoc(obj) or ""
    if isinstance(obj, type) and doc == inspect.getdoc(type):
        return ""
    para = " ".join(doc.strip().split("\n\n")[0].split())
    para = _ROLE.sub(r"`\1`", para)
    match = re.match(r"(.+?[.!?])\s+(?=[A-Z])", para)  # the first sentence ("eq. (11)" is not one)
    text = match.group(1) if match else para
    if len(text) > 160:
        text = text[:157].rsplit(" ", 1)[0] + " ..."
    return text.replace("|", "\\|")


def _kind(obj: object) -> str:
    if inspect.ismodule(obj):
        return "module"
    if inspect.isclass(obj):
        return "class"
    if callable(obj):
        return "function"
    return "data"


def _module_section(mod_name: str, level: int) -> list[str]:
    lines = [
        f"::: {mod_name}",
        "    options:",
        "      members: false",
        f"      heading_level: {level}",
        "      show_root_heading: true",
        "      show_root_full_path: true",
        "",
    ]
    names = public_names(mod_name)
    if names:
        lines += ["| name | kind | what |", "|---|---|---|"]
        mod = module(mod_name)
        for name in names:
            obj = getattr(mod, name)
            target = home(mod_name, name)
            lines.append(f"| [`{name}`][{target}] | {_kind(obj)} | {summary(obj)} |")
        lines.append("")
    for name in names:
        obj = getattr(module(mod_name), name)
        if not inspect.ismodule(obj) and _homes()[(mod_name, name)] == mod_name:
            lines += [
                f"::: {mod_name}.{name}",
                "    options:",
                f"      heading_level: {level + 1}",
                "      show_root_heading: true",
                "      show_root_full_path: false",
                "",
            ]
    return lines


def reference_pages() -> dict[str, str]:
    """Page path -> Markdown of every reference page, the index first."""
    groups: dict[str, list[str]] = {}
    for mod_name in public_modules():
        groups.setdefault(page_of(mod_name), []).append(mod_name)
    pages: dict[str, str] = {}
    index = [
        f"# {NAV_TITLE}",
        "",
        "Generated from the docstrings at every build: one page per subpackage, a section per "
        "public module with the table of its public names (its `__all__`), each linked to the "
        "one place it is documented (the module that defines it). Import names from the "
        "subpackage (`from tof_fpn_torch.runtime import FPNFilter`); the most used ones are "
        "also at the top level (`from tof_fpn_torch import FPNFilter`).",
        "",
        "| page | modules |",
        "|---|---|",
    ]
    for path, mods in groups.items():
        top = mods[0]
        rest = ", ".join(f"`{m[len(top) + 1 :]}`" for m in mods[1:])
        index.append(f"| [`{top}`]({path.split('/', 1)[1]}) | {rest} |")
        lines: list[str] = []
        for i, mod_name in enumerate(mods):
            lines += _module_section(mod_name, 1 if i == 0 else 2)
        pages[path] = "\n".join(lines) + "\n"
    return {f"{REFERENCE_DIR}/index.md": "\n".join(index) + "\n", **pages}


def cli_page() -> str:
    """Every ``tof-fpn`` command's ``--help``, from the parser itself."""
    cli = importlib.import_module(f"{PACKAGE}.cli")
    with _columns(96):
        parser = cli.build_parser()
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        lines = [
            f"# {CLI_NAV_TITLE}",
            "",
            "Generated from the parser at every build (`tof-fpn COMMAND --help` prints the same). "
            "`python -m tof_fpn_torch` is the same program. A bad argument is a one-line error "
            "naming it, with exit status 2; a file system error exits with 1.",
            "",
            "```text",
            parser.format_help().rstrip(),
            "```",
            "",
        ]
        for name, command in sub.choices.items():
            lines += [
                f"## tof-fpn {name}",
                "",
                "```text",
                command.format_help().rstrip(),
                "```",
                "",
            ]
    return "\n".join(lines)


@contextlib.contextmanager
def _columns(width: int):
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(width)
    try:
        yield
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old


def nav() -> list[dict[str, str]]:
    pages = reference_pages()
    return [{("Overview" if p.endswith("index.md") else p.split("/")[-1][:-3]): p} for p in pages]


# --- MkDocs hooks ------------------------------------------------------------------------------


def on_config(config):
    """Put the generated pages into the navigation: the entries titled CLI_NAV_TITLE and
    NAV_TITLE in mkdocs.yml are replaced."""
    for i, item in enumerate(config.nav or []):
        if isinstance(item, dict) and NAV_TITLE in item:
            config.nav[i] = {NAV_TITLE: nav()}
        elif isinstance(item, dict) and CLI_NAV_TITLE in item:
            config.nav[i] = {CLI_NAV_TITLE: CLI_PAGE}
    return config


def on_files(files, config):
    from mkdocs.structure.files import File

    generated = {**reference_pages(), CLI_PAGE: cli_page()}
    for path, text in generated.items():
        old = files.get_file_from_path(path)
        if old is not None:
            files.remove(old)
        files.append(File.generated(config, path, content=text))
    return files
