"""``cocd bench upgrade DIR``: result files of earlier versions under the current names.

Renames the columns of :data:`cocd.bench.schema.RENAMED` in every ``*.csv``, in
the header of every Markdown table (``*.md`` and the summaries kept in
``*.meta.json``) below ``DIR``; the values are unchanged, except ``warm``'s
``yes``/``no``, which become ``start``'s ``warm``/``cold``. Each record gains
``columns_renamed`` (what and when), which ``cocd bench readme`` states.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from pathlib import Path

import pandas as pd

from cocd.bench import schema
from cocd.errors import CocdError

__all__ = ["upgrade_folder", "upgrade_markdown"]


def upgrade_folder(folder: Path, *, dry_run: bool = False) -> dict[Path, dict[str, str]]:
    """Rename old columns in every result file below ``folder``; what was renamed, by file.

    With ``dry_run`` nothing is written.

    Raises
    ------
    CocdError
        When ``folder`` is not a folder or a file cannot be read or written.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise CocdError(f"{folder} is not a folder of results")
    done: dict[Path, dict[str, str]] = {}
    texts: dict[Path, str] = {}
    for path in sorted(folder.rglob("*")):
        if not path.is_file() or any(p.startswith(".") for p in path.relative_to(folder).parts):
            continue
        try:
            renamed, text = _upgraded(path)
        except (OSError, ValueError, pd.errors.ParserError) as exc:
            raise CocdError(f"cannot upgrade {path}: {exc}") from None
        if renamed:
            done[path], texts[path] = renamed, text
    if not dry_run:  # every file was read before any is written
        for path, text in texts.items():
            _write_text(path, text)
        for meta_path in sorted({m for p in done for m in p.parent.glob("*.meta.json")}):
            _record(meta_path, done)
    return done


def upgrade_markdown(text: str) -> tuple[str, dict[str, str]]:
    """``text`` with its Markdown tables' old column names replaced; what was renamed."""
    lines = text.split("\n")
    renamed: dict[str, str] = {}
    k = 0
    while k + 1 < len(lines):
        if _is_row(lines[k]) and _is_rule(lines[k + 1]):
            cells = _cells(lines[k])
            names = [c.strip() for c in cells]
            new = [
                schema.RENAMED[n] if n in schema.RENAMED and schema.RENAMED[n] not in names else n
                for n in names
            ]
            if new != names:
                renamed.update({o: n for o, n in zip(names, new, strict=True) if o != n})
                lines[k] = _join([_fit(c, n) for c, n in zip(cells, new, strict=True)])
                warm = [
                    j for j, (o, n) in enumerate(zip(names, new, strict=True)) if o != n == "start"
                ]
                j = k + 2
                while j < len(lines) and _is_row(lines[j]):
                    if warm:
                        row = _cells(lines[j])
                        if len(row) == len(cells):
                            for c in warm:
                                value = row[c].strip()
                                row[c] = _fit(
                                    row[c], {"yes": "warm", "no": "cold"}.get(value, value)
                                )
                            lines[j] = _join(row)
                    j += 1
                k = j
                continue
        k += 1
    return "\n".join(lines), renamed


# -- helpers -------------------------------------------------------------------
def _upgraded(path: Path) -> tuple[dict[str, str], str]:
    """What would be renamed in ``path`` and its text after (empty when nothing)."""
    name = path.name
    if name.endswith(".csv"):
        # As text: the values are written back as they were (an integer column with
        # a blank is not made floats).
        table = pd.read_csv(path, dtype=str, keep_default_na=False)
        new = schema.upgrade(table)
        renamed = {o: n for o, n in zip(table.columns, new.columns, strict=True) if o != n}
        return renamed, new.to_csv(index=False) if renamed else ""
    if name.endswith(".meta.json"):
        meta = json.loads(path.read_text())
        text, renamed = upgrade_markdown(str(meta.get("summary", "")))
        meta["summary"] = text
        return renamed, json.dumps(meta, indent=2) + "\n"
    if name.endswith(".md"):
        text, renamed = upgrade_markdown(path.read_text())
        return renamed, text
    return {}, ""


def _record(meta_path: Path, done: dict[Path, dict[str, str]]) -> None:
    """Add to a record what was renamed in its own files (and itself), and when."""
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, json.JSONDecodeError):
        return
    own = {meta_path.name, *map(str, meta.get("files", []))}
    renamed: dict[str, str] = {}
    for path, names in done.items():
        if path.parent == meta_path.parent and path.name in own:
            renamed.update(names)
    if not renamed:
        return
    earlier = meta.get("columns_renamed", {}).get("names", {})
    meta["columns_renamed"] = {
        "names": {**earlier, **renamed},
        "on": _dt.date.today().isoformat(),
        "by": "cocd bench upgrade",
    }
    _write_text(meta_path, json.dumps(meta, indent=2) + "\n")


def _write_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def _is_row(line: str) -> bool:
    return line.startswith("|") and line.rstrip().endswith("|")


def _is_rule(line: str) -> bool:
    return _is_row(line) and set(line.strip()) <= set("|:- ")


def _cells(line: str) -> list[str]:
    return line.rstrip()[1:-1].split("|")


def _join(cells: list[str]) -> str:
    return "|" + "|".join(cells) + "|"


def _fit(cell: str, text: str) -> str:
    """``text`` in place of ``cell``'s content, keeping its width where it fits."""
    width = len(cell) - 2
    if len(text) > width:
        return f" {text} "
    right = cell.startswith(" " * 2) and not cell.endswith(" " * 2)
    return f" {text.rjust(width) if right else text.ljust(width)} "
