"""Griffe extension for the API reference: the package's docstrings as Markdown.

The docstrings are Google style with a few conventions griffe does not read, so the text shown is
adapted here (the package is not touched):

* Sphinx roles in the prose (``:func:`valid_mask```) become code spans;
* a ``#:`` comment block right above an attribute without a docstring becomes its docstring
  (``constants.py``);
* ``Example:`` (an admonition for griffe) becomes ``Examples:``, so doctests render as code;
* ``Args:`` entries may name several parameters at once (``height, width: ...``). griffe's own
  check of documented parameters cannot read that (``warn_unknown_params`` is off in
  ``mkdocs.yml``), so this extension checks every name of every entry against the signature and
  warns (a failure of ``mkdocs build --strict``) for a name the signature does not have.
"""

from __future__ import annotations

import re

import griffe

_ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|attr|data|exc|obj|const|ref):`~?([^`]+)`")
_EXAMPLE = re.compile(r"^(\s*)Example:\s*$", re.M)
_logger = griffe.logger


class MarkdownDocstrings(griffe.Extension):
    def on_instance(self, *, obj, **kwargs) -> None:
        if obj.is_alias:
            return
        if obj.docstring is None and obj.is_attribute:
            comment = _comment_above(obj)
            if comment:
                obj.docstring = griffe.Docstring(comment, lineno=obj.lineno, parent=obj)
        if obj.docstring is not None:
            text = _ROLE.sub(r"`\1`", obj.docstring.value)
            obj.docstring.value = _EXAMPLE.sub(r"\1Examples:", text)

    def on_package(self, *, pkg, **kwargs) -> None:
        for obj in _walk(pkg):
            _check_parameters(obj)


def _comment_above(obj) -> str:
    try:
        lines = obj.module.lines
    except Exception:  # noqa: BLE001 - no source: nothing to read
        return ""
    if not lines or not obj.lineno or obj.lineno > len(lines):
        return ""
    found: list[str] = []
    i = obj.lineno - 2
    while 0 <= i < len(lines) and lines[i].lstrip().startswith("#:"):
        found.append(lines[i].lstrip()[2:].strip())
        i -= 1
    return " ".join(reversed(found))


def _walk(obj):
    yield obj
    for member in obj.members.values():
        if not member.is_alias:
            yield from _walk(member)


def _check_parameters(obj) -> None:
    if obj.docstring is None or not (obj.is_function or obj.is_class):
        return
    if obj.is_function:
        signature = obj.parameters
    elif "__init__" in obj.members and not obj.members["__init__"].is_alias:
        signature = obj.members["__init__"].parameters
    else:
        return
    known = {p.name for p in signature}
    variadic = any(p.kind and p.kind.value.startswith("variadic") for p in signature)
    sections = griffe.parse_google(
        obj.docstring, warn_unknown_params=False, warn_missing_types=False
    )
    for section in sections:
        if section.kind is not griffe.DocstringSectionKind.parameters:
            continue
        for param in section.value:
            for name in (n.strip().lstrip("*") for n in param.name.split(",")):
                if name and name not in known and not variadic:
                    _logger.warning(
                        f"{obj.relative_filepath}:{obj.docstring.lineno}: {obj.path}: "
                        f"documented parameter {name!r} is not in the signature"
                    )
