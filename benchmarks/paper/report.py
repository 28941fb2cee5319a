"""Writing an experiment's results: one CSV, JSON, Markdown and PNG file each, named alike."""

from __future__ import annotations

import csv
import json
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

__all__ = ["write_report"]


def write_report(
    out: str | Path,
    stem: str,
    result: dict,
    fields: Sequence[str],
    rows: Iterable[dict],
    markdown: str,
    plot: Callable[[dict, Path], Path],
) -> dict[str, Path]:
    """Write ``<stem>.csv`` (``rows`` restricted to ``fields``), ``<stem>.json`` (``result``),
    ``<stem>.md`` (``markdown``) and ``<stem>.png`` (``plot(result, path)``) into ``out``.

    Returns ``{"csv": path, "json": path, "md": path, "png": path}``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {k: out / f"{stem}.{k}" for k in ("csv", "json", "md", "png")}
    with open(paths["csv"], "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=list(fields))
        wr.writeheader()
        for r in rows:
            wr.writerow({k: r.get(k) for k in fields})
    paths["json"].write_text(json.dumps(result, indent=1))
    paths["md"].write_text(markdown)
    plot(result, paths["png"])
    return paths
