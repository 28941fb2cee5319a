"""The documentation's figures and result files: none missing, none orphaned, each made by one command.

* every image or data file a page links to, and every ``docs/figures/...`` path a page, the README
  or ``mkdocs.yml`` names, exists;
* every file in ``docs/figures/`` (recursively) is referenced from a page or the README, outside
  the registry below (a file named by a subfolder's path, e.g. ``docs/figures/table2/``, counts
  as referenced);
* every such file is in the registry: the table under "Regenerating the figures" in
  ``docs/benchmarks.md``, one row per command (``| `file`, `file` | `command` |``), each file
  in one row only, its script present.

The checks are functions of the repository's root, so that ``test_the_checks_can_fail`` runs
them on a small made-up tree with a missing, an orphaned and an unregistered file.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: the page that holds the registry, and the registry's heading
REGISTRY_PAGE = "docs/benchmarks.md"
REGISTRY_HEADING = "## Regenerating the figures"

#: a link's target counts as an image or data file when it ends in one of these
DATA_SUFFIXES = {".png", ".jpg", ".jpeg", ".gif", ".svg", ".json", ".csv", ".npz", ".npy", ".txt"}

_LINK = re.compile(r"\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
#: ``figures/...`` or ``docs/figures/...``, up to a character that cannot be in a path
_FIGURE = re.compile(r"(?<![\w/.-])(?:docs/)?figures/([\w./<>*-]*)")
_CODE = re.compile(r"`([^`]+)`")


def source_pages(root: Path) -> list[Path]:
    """The pages whose references count: docs/**/*.md (not the result tables in docs/figures,
    not the build tooling), README.md and mkdocs.yml."""
    docs = root / "docs"
    found = [
        p
        for p in sorted(docs.rglob("*.md"))
        if "_tooling" not in p.relative_to(docs).parts
        and "figures" not in p.relative_to(docs).parts
    ]
    for name in ("README.md", "mkdocs.yml"):
        if (root / name).is_file():
            found.append(root / name)
    return found


def split_registry(text: str) -> tuple[str, str]:
    """``(text without the registry section, the registry section)``."""
    start = text.find("\n" + REGISTRY_HEADING + "\n")
    if start < 0:
        return text, ""
    end = text.find("\n## ", start + 1)
    end = len(text) if end < 0 else end
    return text[:start] + text[end:], text[start:end]


def figure_mentions(text: str) -> set[str]:
    """The paths under docs/figures that ``text`` names, relative to docs/figures (a folder with
    a trailing ``/``); patterns (``<case>``, ``*``) and the folder itself are left out."""
    out = set()
    for m in _FIGURE.finditer(text):
        rel = m.group(1).rstrip(".")
        if not rel or "<" in rel or ">" in rel or "*" in rel:
            continue
        out.add(rel)
    return out


def references(root: Path) -> tuple[dict[str, set[str]], list[tuple[str, Path]]]:
    """``(figures, links)``: every docs/figures path named outside the registry with the pages
    that name it, and every (page, resolved target) of a link to an image or data file."""
    figs = (root / "docs" / "figures").resolve()
    figures: dict[str, set[str]] = {}
    links: list[tuple[str, Path]] = []
    for page in source_pages(root):
        text = page.read_text(encoding="utf-8")
        if page.relative_to(root).as_posix() == REGISTRY_PAGE:
            text, _ = split_registry(text)
        name = page.relative_to(root).as_posix()
        for rel in figure_mentions(text):
            if not rel.endswith("/") and (root / "docs/figures" / rel).is_dir():
                rel += "/"  # a folder named without its slash
            figures.setdefault(rel, set()).add(name)
        for target in _LINK.findall(text):
            if re.match(r"[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
                continue  # a URL or an anchor on the same page
            path = target.split("#", 1)[0]
            resolved = (page.parent / path).resolve()
            if resolved.is_relative_to(figs) and resolved != figs:
                # ./figures/x.png, ../docs/figures/x.png: a reference like figures/x.png
                figures.setdefault(resolved.relative_to(figs).as_posix(), set()).add(name)
            if Path(path).suffix.lower() in DATA_SUFFIXES:
                links.append((name, resolved))
    return figures, links


def registry(root: Path) -> dict[str, str]:
    """``{path relative to docs/figures: command}`` from the registry table."""
    page = root / REGISTRY_PAGE
    _, section = split_registry(page.read_text(encoding="utf-8")) if page.is_file() else ("", "")
    out: dict[str, str] = {}
    duplicates = []
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 2 or not cells[0].startswith("`"):
            continue  # the header, the rule, text
        files = [c for c in _CODE.findall(cells[0])]
        commands = _CODE.findall(cells[1])
        assert len(commands) == 1, f"one command per registry row: {line}"
        for f in files:
            assert f.startswith("docs/figures/"), f"registry paths start with docs/figures/: {f}"
            rel = f[len("docs/figures/") :]
            if rel in out:
                duplicates.append(rel)
            out[rel] = commands[0]
    assert not duplicates, f"files registered in more than one row: {duplicates}"
    return out


def _covered(rel: str, names: set[str] | dict[str, object]) -> bool:
    """``rel`` (a file under docs/figures) is named itself or by one of its subfolders."""
    if rel in names:
        return True
    parts = rel.split("/")
    return any("/".join(parts[:i]) + "/" in names for i in range(1, len(parts)))


def figure_files(root: Path) -> list[str]:
    figs = root / "docs" / "figures"
    return sorted(p.relative_to(figs).as_posix() for p in figs.rglob("*") if p.is_file())


def missing_references(root: Path) -> list[str]:
    """(a) references to files that do not exist, as ``page: path`` (a link into docs/figures is
    reported once, as its docs/figures path)."""
    figs = root / "docs" / "figures"
    figures, links = references(root)
    listed = registry(root)
    bad = [
        f"{', '.join(sorted(pages))}: docs/figures/{rel}"
        for rel, pages in sorted(figures.items())
        if not (figs / rel).exists()
    ]
    bad += [
        f"{page}: {target}"
        for page, target in links
        if not target.exists() and not target.is_relative_to(figs.resolve())
    ]
    bad += [
        f"{REGISTRY_PAGE} (registry): docs/figures/{rel}"
        for rel in sorted(listed)
        if not (figs / rel).exists()
    ]
    return bad


def orphans(root: Path) -> list[str]:
    """(b) files in docs/figures that no page or the README references (outside the registry)."""
    figures, _ = references(root)
    return [f"docs/figures/{rel}" for rel in figure_files(root) if not _covered(rel, figures)]


def unregistered(root: Path) -> list[str]:
    """(c) files referenced from a page or present in docs/figures without a registry row."""
    figs = root / "docs" / "figures"
    figures, _ = references(root)
    listed = registry(root)
    named = {rel for rel in figures if (figs / rel).is_file()}
    return [
        f"docs/figures/{rel}"
        for rel in sorted(named | set(figure_files(root)))
        if not _covered(rel, listed)
    ]


def bad_commands(root: Path) -> list[str]:
    """Registry commands whose script (``python X.py``) or subcommand (``tof-fpn SUB``) is not
    there."""
    bad = []
    for command in sorted(set(registry(root).values())):
        for part in command.split("&&"):
            words = shlex.split(part)
            if words[:1] == ["python"] and len(words) > 1 and words[1].endswith(".py"):
                if not (root / words[1]).is_file():
                    bad.append(f"{command}: no {words[1]}")
            elif words[:1] == ["tof-fpn"]:
                if len(words) < 2 or not (root / "tof_fpn_torch/cli" / f"{words[1]}.py").is_file():
                    bad.append(f"{command}: no tof-fpn subcommand {words[1:2]}")
            elif words[:1] != ["cp"]:
                bad.append(f"{command}: neither python SCRIPT, tof-fpn nor cp: {part.strip()}")
    return bad


def test_referenced_files_exist():
    bad = missing_references(ROOT)
    assert not bad, "referenced files that do not exist:\n" + "\n".join(bad)


def test_no_orphaned_figures():
    bad = orphans(ROOT)
    assert not bad, "files in docs/figures that no page references:\n" + "\n".join(bad)


def test_every_figure_has_a_command():
    bad = unregistered(ROOT)
    assert not bad, f"files without a row in {REGISTRY_PAGE}'s registry:\n" + "\n".join(bad)
    bad = bad_commands(ROOT)
    assert not bad, "registry commands that cannot run:\n" + "\n".join(bad)


def test_the_registry_is_read():
    """The parser finds the registry's rows (an empty registry would pass the checks above only
    if docs/figures were empty, but say so plainly)."""
    listed = registry(ROOT)
    assert listed.get("demo.png") == "tof-fpn demo --out docs/figures"
    assert (
        listed.get("table2/") == "python benchmarks/reproduce.py table2 --out docs/figures/table2"
    )
    assert len(listed) >= 20


def _write(path: Path, text: str = "x") -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")


def test_the_checks_can_fail(tmp_path):
    """A made-up tree: the checks name exactly its missing, orphaned and unregistered files."""
    root = tmp_path
    _write(
        root / "docs/guide.md",
        "![a](./figures/a.png) [table](figures/sub/t.md) `docs/figures/b.json`\n"
        "![gone](figures/gone.png) [data](../data/missing.csv) per case: "
        "`docs/figures/x_<case>.png`, all: `docs/figures/`\n",
    )
    _write(
        root / REGISTRY_PAGE,
        "# Benchmarks\n\nsee `docs/figures/c.json`.\n\n"
        f"{REGISTRY_HEADING}\n\n| files | command |\n|---|---|\n"
        "| `docs/figures/a.png`, `docs/figures/c.json` | `tof-fpn demo --out docs/figures` |\n"
        "| `docs/figures/sub/` | `python benchmarks/run.py --out docs/figures/sub` |\n"
        "| `docs/figures/orphan.png` | `python benchmarks/nowhere.py` |\n"
        "\n## After\n\ntext `docs/figures/sub/u.csv`\n",
    )
    _write(root / "README.md", "![demo](docs/figures/a.png)\n")
    _write(root / "tof_fpn_torch/cli/demo.py")
    _write(root / "benchmarks/run.py")
    for rel in ("a.png", "b.json", "c.json", "orphan.png", "sub/t.md", "sub/u.csv"):
        _write(root / "docs/figures" / rel)

    assert missing_references(root) == [
        "docs/guide.md: docs/figures/gone.png",
        f"docs/guide.md: {(root / 'data/missing.csv').resolve()}",
    ]
    # orphan.png is named only by the registry: not a reference
    assert orphans(root) == ["docs/figures/orphan.png"]
    assert unregistered(root) == ["docs/figures/b.json"]
    assert bad_commands(root) == ["python benchmarks/nowhere.py: no benchmarks/nowhere.py"]

    # registered, referenced and present: nothing reported
    _write(root / "docs/figures/gone.png")
    (root / "docs/figures/orphan.png").unlink()
    _write(root / "data/missing.csv")
    text = (root / REGISTRY_PAGE).read_text()
    text = text.replace(
        "`docs/figures/orphan.png` | `python benchmarks/nowhere.py`",
        "`docs/figures/b.json`, `docs/figures/gone.png` | `python benchmarks/run.py`",
    )
    (root / REGISTRY_PAGE).write_text(text)
    assert missing_references(root) == []
    assert orphans(root) == []
    assert unregistered(root) == []
    assert bad_commands(root) == []
