"""How ``tof-fpn clean`` is put together (docs/adding-a-stage.md): the steps' outputs are read from
their records, never probed with ``getattr`` / ``hasattr``; the configuration's keys, TOML tables and
flags come from the declared options, each once."""

from __future__ import annotations

import ast
from pathlib import Path

from tof_fpn_torch.clean import CleanConfig, config_from_dict, config_to_toml
from tof_fpn_torch.clean.config import all_options, reference
from tof_fpn_torch.clean.steps import FILE_OPTIONS, Option, TableOption, options, steps
from tof_fpn_torch.cli import build_parser

CLEAN = Path(__file__).resolve().parents[1] / "tof_fpn_torch" / "clean"
#: (file, first argument) of the getattr calls allowed in clean/, each with its reason
ALLOWED = {
    # the DataLoader iterator's private shutdown, which a killed run calls if it exists
    ("local.py", "it"),
}


def _probes(root: Path) -> list[tuple[str, int, str]]:
    found = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
                if node.func.id in ("getattr", "hasattr"):
                    first = ast.unparse(node.args[0]) if node.args else ""
                    if (path.name, first) not in ALLOWED or node.func.id == "hasattr":
                        found.append((str(path.relative_to(root)), node.lineno, node.func.id))
    return found


def test_no_getattr_or_hasattr_probes_in_clean():
    assert _probes(CLEAN) == []


def test_the_probe_finder_finds_probes(tmp_path):
    (tmp_path / "a.py").write_text(
        "x = getattr(p, 'last_flying', None)\nif hasattr(p, 'g'): pass\n"
    )
    assert _probes(tmp_path) == [("a.py", 1, "getattr"), ("a.py", 2, "hasattr")]


def test_every_option_is_declared_once_and_reaches_toml_and_cli():
    names = [o.name for o in [*options(), *FILE_OPTIONS]]
    assert len(names) == len(set(names)) == len(all_options())
    help_text = build_parser()._subparsers._group_actions[0].choices["clean"].format_help()
    text = reference()
    for o in all_options().values():
        if isinstance(o, TableOption):
            assert f"--{o.flag}" in help_text and f"[{o.table}]" in text
            continue
        assert isinstance(o, Option)
        flag = o.cli_flag()
        if o.setting.kind is bool and o.setting.default is True:
            flag = f"no-{flag}"
        assert f"--{flag}" in help_text, o.name
        assert f"\n{o.key} = " in text or text.startswith(f"[{o.table}]\n{o.key} = "), o.name


def test_a_config_round_trips_through_toml():
    c = CleanConfig(
        stage="paper",
        destripe="rows",
        denoise="nlm",
        denoise_options={"h": 0.5},
        flying="reassign",
        temporal=True,
        temporal_guard=float("inf"),
        batch=3,
    )
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib

    back = config_from_dict(tomllib.loads(config_to_toml(c)))
    assert back == c and back.temporal_guard == float("inf")
    assert [s.name for s in steps()] == ["pattern", "fpn", "flying", "denoise", "temporal"]


def test_the_guide_lists_every_key():
    """docs/clean.md's configuration file names every table and key the steps declare."""
    import re

    page = (Path(__file__).resolve().parents[1] / "docs" / "clean.md").read_text()
    block = re.search(r"<!-- docs-test: file clean.toml -->\s*```toml\n(.*?)```", page, re.S)
    assert block
    listed, table = set(), None
    for line in block.group(1).splitlines():
        m = re.match(r"\[(\w+)\]", line)
        if m:
            table = m.group(1)
            listed.add((table, "*"))
            continue
        m = re.match(r"#?\s*(\w+)\s*=", line)
        if m:
            listed.add((table, m.group(1)))
    declared = {
        (o.table, "*") if isinstance(o, TableOption) else (o.table, o.key)
        for o in all_options().values()
    }
    assert declared <= listed, sorted(declared - listed)
