"""Result files with their provenance, and ``results/README.md`` rebuilt from them.

Every harness command writes its tables (CSV and Markdown) and plots (PNG)
under an output directory, plus ``<name>.meta.json``: the title, the command
line that made them, the machine (CPU, cores, memory, package versions), the
time written and a short Markdown summary. :func:`write_readme` rebuilds
``README.md`` in that directory from every ``*.meta.json`` it finds, adding
the commentary a person wrote in ``notes/<name>.md`` when there is one, so
that the README always shows each table and plot with the command and
machine that made it.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import platform
import re
import shlex
import sys
import time
from collections.abc import Callable, Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

import pandas as pd

from cocd.bench import estimate, schema
from cocd.errors import CocdError

__all__ = [
    "command_line",
    "fill_note",
    "machine_info",
    "machine_line",
    "throttled",
    "write_meta",
    "write_readme",
    "write_table",
]

#: Sections of the README, in this order; other names follow alphabetically.
ORDER = [
    "table1",
    "seed_contacts",
    "margin",
    "scaling",
    "stability",
    "precision",
    "hard",
    "external",
    "peers",
    "backends",
    "iterative",
    "collapse_2d_slope",
    "timestep",
    "nscd",
    "erodible",
    "stability_threshold",
    "runout_scaling",
    "avalanche",
]

PACKAGES = [
    "numpy",
    "scipy",
    "numba",
    "clarabel",
    "scs",
    "ecos",
    "cvxpy",
    "qpsolvers",
    "osqp",
    "proxsuite",
    "piqp",
    "daqp",
    "highspy",
    "quadprog",
    "mosek",
    "qdldl",
    "cvxopt",
    "pypardiso",
    "h5py",
]


def machine_info() -> dict[str, Any]:
    """CPU model, cores, memory, OS, Python and the versions of the numerical packages."""
    from cocd.provenance import cpu_name, provenance

    try:
        memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 2**30
    except (ValueError, OSError):
        memory = float("nan")
    versions = {}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return {
        "software": provenance(),
        "cpu": cpu_name(),
        "cores": os.cpu_count(),
        "memory_gib": round(memory, 1),
        "os": f"{platform.system()} {platform.release()}",
        "python": platform.python_version(),
        "packages": versions,
    }


def machine_line(info: dict[str, Any] | None = None) -> str:
    """One line: ``CPU, n cores, m GiB, Python x; package versions``."""
    info = info or machine_info()
    versions = ", ".join(f"{k} {v}" for k, v in info["packages"].items())
    return (
        f"{info['cpu']}, {info['cores']} cores, {info['memory_gib']:g} GiB, "
        f"Python {info['python']}; {versions}"
    )


def command_line() -> str:
    """The command that is running, as a user would type it."""
    argv = list(sys.argv)
    prog = Path(argv[0]).name if argv else "python"
    if prog in ("cocd", "__main__.py"):
        argv[0] = "cocd"
    elif argv and argv[0].endswith(".py"):
        argv = ["python", os.path.relpath(argv[0]), *argv[1:]]
    return shlex.join(argv)


def write_table(
    out: Path,
    name: str,
    table: pd.DataFrame,
    *,
    title: str,
    command: str | None = None,
    intro: str = "",
    floatfmt: str = ".3g",
) -> list[Path]:
    """Write ``<name>.csv`` and ``<name>.md`` (title, command, machine, table)."""
    out.mkdir(parents=True, exist_ok=True)
    command = command or command_line()
    csv = out / f"{name}.csv"
    md = out / f"{name}.md"
    table.to_csv(csv, index=False)
    with open(md, "w") as f:
        f.write(f"# {title}\n\n`{command}`\n\nMachine: {machine_line()}\n\n")
        if intro:
            f.write(intro.strip() + "\n\n")
        f.write(table.to_markdown(index=False, floatfmt=floatfmt))
        f.write("\n")
    return [csv, md]


def publish(
    out: Path,
    name: str,
    table: pd.DataFrame,
    *,
    title: str,
    intro: str = "",
    summary: str = "",
    figures: Sequence[Path] = (),
) -> list[Path]:
    """Write a study's main table (:func:`write_table`) and its record (:func:`write_meta`,
    listing ``figures`` too); the files written. ``OUT/README.md`` is rebuilt when the
    study returns (:class:`cocd.bench.study.Study`)."""
    files = [*write_table(out, name, table, title=title, intro=intro), *figures]
    write_meta(out, name, title=title, files=files, summary=summary)
    return files


#: What makes two machines alike for a recorded time: processor and cores.
_MACHINE_KEYS = ("cpu", "cores")


def write_meta(
    out: Path,
    name: str,
    *,
    title: str,
    files: list[Path],
    summary: str = "",
    command: str | None = None,
) -> Path:
    """Record the provenance of ``files`` in ``<name>.meta.json``.

    The command's time and work (:func:`cocd.bench.estimate.record`) are recorded when
    it solved something. When it solved nothing (its runs all read back, e.g. to redraw
    a figure), the time and work of an earlier record of the same command stay, with
    when they were taken (``timed``) and, when that was another machine, its processor
    and cores (``timed_on``): the next estimate's rate, and the command's cost, are the
    solves', and a rebuild elsewhere does not lose them.
    """
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.meta.json"
    command = command or command_line()
    machine = machine_info()
    timing: dict[str, Any] = dict(estimate.record())
    if timing.get("work_units") == 0:
        try:
            earlier = json.loads(path.read_text())
            if earlier["command"] == command and float(earlier["work_units"]) > 0:
                timing = {
                    "elapsed_s": earlier["elapsed_s"],
                    "work_units": earlier["work_units"],
                    "workers": earlier.get("workers", 1),
                    "timed": earlier.get("timed", earlier.get("written")),
                }
                where = earlier.get("timed_on") or {
                    key: earlier["machine"].get(key) for key in _MACHINE_KEYS
                }
                if any(where.get(key) != machine.get(key) for key in _MACHINE_KEYS):
                    timing["timed_on"] = where
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            pass
    meta = {
        "name": name,
        "title": title,
        "command": command,
        "machine": machine,
        "written": _dt.datetime.now().isoformat(timespec="seconds"),
        "files": sorted({os.path.relpath(p, out) for p in files}),
        "summary": summary,
        **timing,
    }
    path.write_text(json.dumps(meta, indent=2) + "\n")
    return path


#: Words every README that :func:`write_readme` writes holds: one without them is
#: someone else's, and is not replaced.
README_MARK = "this README is\nrebuilt from their `*.meta.json` by `cocd bench readme`"


def check_readme_ours(out: Path) -> None:
    """Refuse ``out`` when its ``README.md`` was not written by :func:`write_readme`."""
    path = Path(out) / "README.md"
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return
    except (OSError, UnicodeDecodeError) as exc:
        raise CocdError(f"cannot read {path}: {exc}") from None
    if README_MARK not in text:
        raise CocdError(
            f"{path} was not written by cocd, and the results' README would replace it: "
            "move it, or give another --out"
        )


def write_readme(out: Path, *, heading: str | None = None) -> Path:
    """Rebuild ``<out>/README.md`` from every ``<out>/*.meta.json``, under ``# heading``
    (default: the heading the README has, else "Results")."""
    if not out.is_dir():
        raise CocdError(
            f"results directory {out} " + ("is a file" if out.exists() else "does not exist")
        )
    check_readme_ours(out)
    if heading is None:
        heading = "Results"
        try:
            first = (out / "README.md").read_text().splitlines()[0]
        except (OSError, IndexError):
            first = ""
        if first.startswith("# "):
            heading = first[2:].strip()
    metas = []
    for path in out.glob("*.meta.json"):
        try:
            metas.append(json.loads(path.read_text()))
        except (OSError, json.JSONDecodeError):
            continue
    rank = {name: k for k, name in enumerate(ORDER)}
    metas.sort(key=lambda m: (rank.get(m["name"], len(ORDER)), m["name"]))
    lines = [
        f"# {heading}",
        "",
        "Every file here was written by a command of the repository; this README is",
        "rebuilt from their `*.meta.json` by `cocd bench readme` (commentary from",
        "`notes/<name>.md`). All residuals are the framework's (`cocd.residuals`),",
        "the same for every backend.",
        "",
        "The tables share the names below for the same quantities (`cocd.bench.schema`);",
        "a row over a sequence of step problems gives means of times and iterations",
        "and maxima of residuals. Tables of earlier versions are read under these",
        "names, and `cocd bench upgrade DIR` rewrites them.",
        "",
        "<details><summary>Columns</summary>",
        "",
        schema.markdown(),
        "",
        "</details>",
        "",
    ]
    for meta in metas:
        lines += [f"## {meta['title']}", "", "```bash", meta["command"], "```", ""]
        lines += [
            f"Machine: {machine_line(meta['machine'])}. Written {meta['written']}.",
            "",
        ]
        files = meta.get("files", [])
        lines.append("Files: " + ", ".join(f"[`{f}`]({f})" for f in files) + ".")
        lines.append("")
        renamed = meta.get("columns_renamed")
        if renamed:
            pairs = ", ".join(f"`{o}` -> `{n}`" for o, n in renamed["names"].items())
            lines += [
                f"Columns renamed by `{renamed['by']}` on {renamed['on']} (values "
                f"unchanged): {pairs}.",
                "",
            ]
        if meta.get("summary"):
            lines += [meta["summary"].strip(), ""]
        for f in files:
            if f.endswith(".png"):
                lines += [f"![{f}]({f})", ""]
        note = out / "notes" / f"{meta['name']}.md"
        if note.exists():
            lines += [fill_note(note.read_text(), out, note.name).strip(), ""]
    readme = out / "README.md"
    readme.write_text("\n".join(lines).rstrip() + "\n", encoding="utf-8")
    return readme


_PLACEHOLDER = re.compile(
    r"\{\{\s*(?:(?P<agg>min|max|mean|count|same)\s+)?(?P<table>[\w-]+(?:/[\w-]+)*)\.(?P<column>\w+)"
    r"\s*(?:\[(?P<where>[^\]]*)\])?\s*(?::(?P<fmt>[^}|]+?))?\s*(?:\|(?P<empty>[^}]+?))?\s*\}\}"
)


def fill_note(text: str, out: Path, name: str = "note") -> str:
    """A note with its numbers filled in from the tables beside it.

    A placeholder ``{{table.column[key=value, ...]:format}}`` is the cell of
    ``out/table.csv`` in ``column`` on the one row whose ``key`` columns hold those
    values (numbers compared to 1e-9 relative); ``table`` may name a folder under ``out``
    (``flume_to4s/flume``: the tables of a study written to ``--out OUT/flume_to4s``);
    ``{{max table.column[...]}}`` (or
    ``min``, ``mean``, ``count``) aggregates the rows that match, and
    ``{{same table.column[...]}}`` is the value they all hold (an error if they
    differ: "each run made 220 steps" is then checked on every run). The format is
    Python's (default ``.3g``). An empty cell (for an aggregate: every cell that
    matches empty) is an error unless the placeholder ends with what to write instead,
    after a bar: ``{{table.column[...]:.2f|not reached}}`` (a rest time that a run did
    not reach). A placeholder that names no table, no column, no row or several rows
    is an error naming it: a note cannot say a number its table does not hold.
    """
    tables: dict[str, pd.DataFrame] = {}

    def value(match: re.Match[str]) -> str:
        where = f"{name}: {match.group(0)}"
        table = match.group("table")
        if table not in tables:
            path = out / f"{table}.csv"
            if not path.exists():
                raise CocdError(f"{where}: no table {path}")
            tables[table] = pd.read_csv(path)
        frame = tables[table]
        column = match.group("column")
        if column not in frame.columns:
            raise CocdError(f"{where}: {table}.csv has no column {column!r}")
        keep = pd.Series(True, index=frame.index)
        for cond in filter(None, (c.strip() for c in (match.group("where") or "").split(","))):
            key, _, want = (part.strip() for part in cond.partition("="))
            if key not in frame.columns or not want:
                raise CocdError(f"{where}: bad condition {cond!r}")
            keep &= _matches(frame[key], want)
        cells = frame.loc[keep, column]
        agg = match.group("agg")
        if agg and agg != "count" and not len(cells):
            raise CocdError(f"{where}: no row matches")
        cell: Any
        if agg == "same":
            cell = _same(cells, where)
        elif agg:
            cell = len(cells) if agg == "count" else getattr(cells, agg)()
        elif len(cells) != 1:
            raise CocdError(f"{where}: {len(cells)} rows match, not one")
        else:
            cell = cells.iloc[0]
        if pd.isna(cell):
            if match.group("empty") is None:
                raise CocdError(f"{where}: the cell is empty")
            return match.group("empty").strip()
        fmt = match.group("fmt") or (".3g" if isinstance(cell, float) else "")
        try:
            return format(cell, fmt)
        except (TypeError, ValueError):
            raise CocdError(f"{where}: format {fmt!r} does not apply to {cell!r}") from None

    filled = _PLACEHOLDER.sub(value, text)
    left = re.search(r"\{\{.*?\}\}", filled, flags=re.S)
    if left:
        raise CocdError(f"{name}: {left.group(0)} is not a placeholder cocd can read")
    return filled


def _same(cells: pd.Series, where: str) -> Any:
    """The value every cell holds (numbers to 1e-9 relative, as rows are matched);
    an error naming a few of them when they differ."""
    numbers = pd.to_numeric(cells, errors="coerce")
    if numbers.notna().all():
        if _close(float(numbers.min()), float(numbers.max())):
            return cells.iloc[0]
    elif len({str(v) for v in cells}) == 1:  # text, or every cell empty
        return cells.iloc[0]
    shown = ", ".join(str(v) for v in cells.drop_duplicates().iloc[:4])
    raise CocdError(f"{where}: the rows that match differ ({shown})")


def _matches(column: pd.Series, want: str) -> pd.Series:
    try:
        number = float(want)
    except ValueError:
        return column.astype(str) == want
    values = pd.to_numeric(column, errors="coerce")
    return values.map(lambda v: _close(v, number)).astype(bool)


def _close(a: float, b: float) -> bool:
    """Equal to 1e-9 relative, as a note's numbers and conditions are compared
    (an infinity equal only to itself, NaN to nothing)."""
    if not (math.isfinite(a) and math.isfinite(b)):
        return a == b
    return abs(a - b) <= 1e-9 * max(abs(a), abs(b), 1e-300)


def throttled(
    progress: Callable[[str], Any],
    seconds: float,
    always: Callable[[str], bool] = lambda line: False,
) -> Callable[[str], None]:
    """``progress`` for the first line, then at most once every ``seconds`` (and for the
    lines ``always`` keeps): recording a trajectory reports every step, and tens of
    lines a second would bury the runs' results."""
    last = -math.inf

    def say(line: str) -> None:
        nonlocal last
        now = time.perf_counter()
        if always(line) or now - last >= seconds:
            last = now
            progress(line)

    return say
