"""The documentation site builds with warnings as errors, and every public name has an entry.

The site is built once (``mkdocs build --strict`` into a temporary folder, as ``.ci/run`` does);
then, independently of the generator (``docs/_tooling/reference.py``), the package is walked:

* **public modules**: every module of ``tof_fpn_torch`` without a dotted component starting with
  ``_`` (``__main__`` left out);
* **public names**: a module's ``__all__``; without one, the top-level ``def`` / ``class`` /
  assignment names of its source that do not start with ``_``.

Each public module must have a primary entry in the site's ``objects.inv``, and so must each
public name, under at least one of the public paths it is exported by (``tof_fpn_torch.FPNFilter``
is documented once, as ``tof_fpn_torch.runtime.fpn_filter.FPNFilter``). Every ``tof-fpn``
command must have a section in the command-line page.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import os
import pkgutil
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # builds the whole site: `python -m pytest -m slow` runs it

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "tof_fpn_torch"


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{proc.stderr[-4000:]}"
    return out


def inventory(site: Path) -> dict[str, int]:
    """Name -> priority of every entry of the site's ``objects.inv`` (Sphinx format 2)."""
    *header, body = (site / "objects.inv").read_bytes().split(b"\n", 4)
    assert header[0] == b"# Sphinx inventory version 2"
    entries = {}
    for line in zlib.decompress(body).decode().splitlines():
        name, _domain_role, priority, *_ = line.split(" ")
        entries[name] = int(priority)
    return entries


def public_modules() -> list[str]:
    pkg = importlib.import_module(PACKAGE)
    names = [PACKAGE]
    for info in pkgutil.walk_packages(pkg.__path__, prefix=PACKAGE + "."):
        if not any(part.startswith("_") for part in info.name.split(".")[1:]):
            names.append(info.name)
    return names


def public_names(module) -> list[str]:
    if hasattr(module, "__all__"):
        return list(module.__all__)
    names = []
    for node in ast.parse(inspect.getsource(module)).body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.append(node.name)
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names += [n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)]
    return [n for n in dict.fromkeys(names) if not n.startswith("_")]


def test_every_public_name_has_a_reference_entry(site):
    primary = {name for name, priority in inventory(site).items() if priority == 1}
    modules = {name: importlib.import_module(name) for name in public_modules()}
    exported = {name: public_names(mod) for name, mod in modules.items()}
    assert len(modules) > 50 and sum(map(len, exported.values())) > 500  # the walk found them
    missing = []
    for mod_name, mod in modules.items():
        if mod_name not in primary:
            missing.append(f"{mod_name} (module)")
        for name in exported[mod_name]:
            obj = getattr(mod, name)
            paths = {f"{other}.{name}" for other in modules if name in exported[other]}
            paths = {p for p in paths if getattr(modules[p.rsplit(".", 1)[0]], name) is obj}
            if inspect.ismodule(obj):
                paths.add(obj.__name__)
            if not paths & primary:
                missing.append(f"{mod_name}.{name}")
    assert not missing, f"{len(missing)} public name(s) without a reference entry: {missing}"


def test_every_command_has_a_section(site):
    from tof_fpn_torch.cli import COMMANDS

    page = (site / "cli" / "index.html").read_text()
    for command in COMMANDS:
        assert f'id="tof-fpn-{command}"' in page, command
        assert f"usage: tof-fpn {command}" in page, command
