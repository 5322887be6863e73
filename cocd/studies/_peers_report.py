"""The tables and the profile of ``cocd bench peers`` (:mod:`cocd.studies.peers`).

From the rows of ``peers.csv``: per file the *target* (the best natural-map
error any peer solver reached, raised to the floor), each side's time to it
(least ``setup_s + solve_s`` over its runs that reached it), their ratio and the
geometric mean of the ratios (``peers_summary``), and the Dolan-Moré
performance profile of every solver of both sides in time to target
(``peers_profile.png``).
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cocd.bench import report
from cocd.bench.metrics import performance_profile, shifted_geometric_mean
from cocd.bench.runner import SHORT_SOLVE_REPEATS, SHORT_SOLVE_S

__all__ = ["findings", "profile_costs", "summarize", "write_report"]

#: The common error of :func:`findings`' second comparison.
COMMON_ERROR = 1e-8


def _seconds(rows: pd.DataFrame) -> pd.Series:
    """Time to answer: ``setup_s + solve_s`` (NaN when either is missing)."""
    setup = pd.to_numeric(rows["setup_s"], errors="coerce")
    solve = pd.to_numeric(rows["solve_s"], errors="coerce")
    return setup + solve


def _label(row: Any) -> str:
    return f"{row.solver} (tol {float(row.tol):.0e})"


def _target(rows: pd.DataFrame, floor: float) -> tuple[float, str]:
    """The best natural-map error of the peer's rows (at least ``floor``), and who reached it."""
    peer = rows[(rows["side"] != "cocd") & np.isfinite(rows["natural_map_error"])]
    if peer.empty:
        return math.nan, ""
    best = peer.loc[peer["natural_map_error"].idxmin()]
    error = float(best["natural_map_error"])
    return max(error, floor), f"{_label(best)}: {error:.2g}"


def _reached(rows: pd.DataFrame, target: float) -> pd.DataFrame:
    """The rows that reached ``target``, with their time to it (``seconds``), fastest first."""
    rows = rows.assign(seconds=_seconds(rows))
    ok = (rows["natural_map_error"] <= target) & np.isfinite(rows["seconds"])
    return rows[ok].sort_values("seconds", kind="stable")


def _answered(table: pd.DataFrame) -> pd.DataFrame:
    tab = table[table["solver"].fillna("").astype(str) != ""].copy()
    tab["natural_map_error"] = pd.to_numeric(tab["natural_map_error"], errors="coerce")
    return tab


def summarize(table: pd.DataFrame, *, peer: str, floor: float) -> pd.DataFrame:
    """One row per problem file: target, each side's best (solver, time), their ratio."""
    records = []
    tab = _answered(table)
    for problem, rows in tab.groupby("problem", sort=True):
        first = rows.iloc[0]
        target, by = _target(rows, floor)
        record: dict[str, Any] = {
            "problem": problem,
            "kind": first["kind"],
            "dim": first["dim"],
            "nc": first["nc"],
            "target": target,
            "target_by": by,
            "cocd_solver": "",
            "cocd_s": math.nan,
            f"{peer}_solver": "",
            f"{peer}_s": math.nan,
            "ratio": math.nan,
            "cocd_best_error": math.nan,
            "note": "",
        }
        cocd = rows[rows["side"] == "cocd"]
        errors = cocd["natural_map_error"].dropna()
        if len(errors):
            best = cocd.loc[errors.idxmin()]
            record["cocd_best_error"] = float(best["natural_map_error"])
        if not math.isfinite(target):
            record["note"] = f"no {peer} answer: no target"
            records.append(record)
            continue
        reached = _reached(rows, target)
        mine, theirs = reached[reached["side"] == "cocd"], reached[reached["side"] != "cocd"]
        if len(theirs):
            record[f"{peer}_solver"] = _label(theirs.iloc[0])
            record[f"{peer}_s"] = float(theirs.iloc[0]["seconds"])
        if len(mine):
            record["cocd_solver"] = _label(mine.iloc[0])
            record["cocd_s"] = float(mine.iloc[0]["seconds"])
            if record[f"{peer}_s"] > 0:
                record["ratio"] = record["cocd_s"] / record[f"{peer}_s"]
        elif len(errors):
            record["cocd_solver"] = "not reached"
            record["note"] = (
                f"cocd's best error {record['cocd_best_error']:.2g} "
                f"({_label(cocd.loc[errors.idxmin()])})"
            )
        else:
            record["cocd_solver"] = "not reached"
            statuses = ", ".join(sorted(set(cocd["status"].astype(str)))) or "no run"
            record["note"] = f"no cocd answer ({statuses})"
        records.append(record)
    return pd.DataFrame(records)


def _short(problem: str) -> str:
    """A file's name without its suffixes and the counters after its iteration tag:
    ``Capsules-i125-1213.hdf5`` gives ``Capsules-i125``."""
    stem = re.sub(r"(\.(dat|hdf5|h5))+$", "", str(problem))
    tagged = re.match(r"(.*?-i\d+)(-|$)", stem)
    return tagged.group(1) if tagged else stem


def findings(table: pd.DataFrame, summary: pd.DataFrame, *, peer: str, floor: float) -> list[str]:
    """What the tables show, as sentences whose numbers are computed here from them."""
    out: list[str] = []
    if summary.empty:
        return out
    ratio = pd.to_numeric(summary["ratio"], errors="coerce")
    keep = np.isfinite(ratio) & (ratio > 0)
    ok = summary[keep].copy()
    ok["ratio"] = ratio[keep].to_numpy()  # (assign() would align an empty frame's index)
    with_target = summary[np.isfinite(summary["target"].astype(float))]
    if len(ok):
        lo, hi = ok.loc[ok["ratio"].idxmin()], ok.loc[ok["ratio"].idxmax()]
        mean = shifted_geometric_mean(ok["ratio"], shift=0.0)
        worse = ok[ok["ratio"] > 3.0]
        out.append(
            f"cocd reaches {peer}'s best error (at least {floor:g}) on {len(ok)} of "
            f"{len(with_target)} files; the geometric mean of cocd's time to it over "
            f"{peer}'s is {mean:.3g}, from {lo['ratio']:.3g} ({_short(lo['problem'])}) to "
            f"{hi['ratio']:.3g} ({_short(hi['problem'])}); "
            + (
                f"{len(worse)} {'file is' if len(worse) == 1 else 'files are'} worse than "
                "3 times: "
                + ", ".join(f"{_short(r.problem)} {r.ratio:.3g}" for r in worse.itertuples())
                if len(worse)
                else "no file is worse than 3 times"
            )
            + "."
        )
        fastest = ok["cocd_solver"].str.replace(r" \(tol .*\)$", "", regex=True)
        counts = fastest.value_counts()
        out.append(
            "cocd's fastest solver to the target: "
            + ", ".join(f"`{name}` on {n}" for name, n in counts.items())
            + "."
        )
    missed = with_target[~with_target["problem"].isin(ok["problem"])]
    for row in missed.itertuples():
        out.append(
            f"{_short(row.problem)}: not reached; target {float(row.target):.2g}, "
            f"cocd's best {float(row.cocd_best_error):.2g}."
        )
    tab = _answered(table)
    tab = tab.assign(seconds=_seconds(tab))
    both, ratios = [], []
    beyond = []
    for problem, rows in tab.groupby("problem", sort=True):
        mine, theirs = rows[rows["side"] == "cocd"], rows[rows["side"] != "cocd"]
        best_mine = mine["natural_map_error"].min()
        best_theirs = theirs["natural_map_error"].min()
        if (
            np.isfinite(best_mine)
            and np.isfinite(best_theirs)
            and best_theirs > max(floor, 10.0 * best_mine)
        ):
            beyond.append(f"{_short(problem)} ({best_mine:.2g} against {best_theirs:.2g})")
        a = mine[mine["natural_map_error"] <= COMMON_ERROR]["seconds"].min()
        b = theirs[theirs["natural_map_error"] <= COMMON_ERROR]["seconds"].min()
        if np.isfinite(a) and np.isfinite(b) and a > 0 and b > 0:
            both.append(problem)
            ratios.append(a / b)
    if ratios:
        out.append(
            f"At a common error of {COMMON_ERROR:g} ({len(both)} files where both sides reach "
            f"it), the geometric mean of cocd's least time over {peer}'s is "
            f"{shifted_geometric_mean(pd.Series(ratios), shift=0.0):.3g}."
        )
    if beyond:
        out.append(
            f"cocd's best error is below {peer}'s best (above {floor:g}) by more than 10 "
            "times on: " + ", ".join(beyond) + "."
        )
    return out


def profile_costs(
    table: pd.DataFrame, summary: pd.DataFrame
) -> tuple[list[str], list[str], np.ndarray]:
    """``(problems, solvers, costs)``: each solver's time to each file's target (inf if
    it did not reach it), over the files that have a target; cocd's solvers first."""
    with_target = summary[np.isfinite(summary["target"].astype(float))]
    problems = [str(p) for p in with_target["problem"]]
    tab = _answered(table)
    tab = tab[tab["problem"].isin(problems)]
    cocd = sorted(set(tab.loc[tab["side"] == "cocd", "solver"].astype(str)))
    others = sorted(set(tab.loc[tab["side"] != "cocd", "solver"].astype(str)))
    solvers = [*cocd, *others]
    costs = np.full((len(problems), len(solvers)), np.inf)
    index = {s: k for k, s in enumerate(solvers)}
    targets = dict(zip(problems, with_target["target"].astype(float), strict=True))
    for i, problem in enumerate(problems):
        reached = _reached(tab[tab["problem"] == problem], targets[problem])
        for solver, seconds in reached.groupby("solver")["seconds"].min().items():
            costs[i, index[str(solver)]] = max(0.0, float(seconds))
    return problems, solvers, costs


def _plot(path: Path, solvers: list[str], costs: np.ndarray, peer: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    finite = costs[np.isfinite(costs)]
    worst = float(finite.max() / max(finite[finite > 0].min(), 1e-12)) if finite.size else 10.0
    taus = np.logspace(0, math.log10(max(10.0, 2.0 * worst)), 300)
    fractions = performance_profile(costs, taus)
    fig, ax = plt.subplots(figsize=(10, 5.5))
    colors = plt.get_cmap("tab10")
    count = {"-": 0, "--": 0}
    for k, solver in enumerate(solvers):
        style = "--" if solver.startswith(f"{peer}:") else "-"
        color = colors(count[style] % 10)
        count[style] += 1
        ax.step(taus, fractions[:, k], where="post", ls=style, color=color, label=solver)
    ax.set_xscale("log")
    ax.set_xlabel("tau (time to target / fastest time to target on the file)")
    ax.set_ylabel("fraction of files")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(
        f"Time to the best natural-map error {peer} reaches, {costs.shape[0]} files "
        f"(solid: cocd, dashed: {peer})",
        fontsize=10,
    )
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_report(
    out: Path,
    table: pd.DataFrame,
    *,
    peer: str,
    tols: list[float],
    time_limit: float,
    floor: float,
    peer_note: str | None = None,
) -> list[Path]:
    """Write ``peers.csv``/``.md``, ``peers_summary.csv``/``.md``, ``peers_profile.png`` and
    ``peers.meta.json``; the files written."""
    table = table.copy()
    for column in ("dim", "nc"):
        table[column] = pd.to_numeric(table[column], errors="coerce").round().astype("Int64")
    title = f"cocd and {peer} on the same problem files"
    tol_text = ", ".join(f"{t:g}" for t in tols)
    intro = (
        f"Every solver of both sides at every tolerance ({tol_text}), {time_limit:g} s per "
        "solve. `natural_map_error` is computed by cocd for every answer, whoever made it "
        "(unscaled natural map of Coulomb's law / max(1, ||q||), on the problem as read). "
        "cocd: `setup_s` is cocd's conversion of the file plus the backend's set-up; the "
        "backends with a local form (note `local form`) solve on W itself, a global "
        "problem's condensed W (its condensation in `setup_s`, as for the peer's condensed "
        f"solvers), and stop on the natural-map error, as {peer}'s solvers stop on theirs. "
        f"A solve under {SHORT_SOLVE_S * 1e3:g} ms (cocd's local forms, the peer's driver "
        f"calls) is run up to {SHORT_SOLVE_REPEATS} times from the same start and its "
        "median time kept. "
        f"{peer}: "
        "`solve_s` is the driver call, `setup_s` cocd's condensation for a `(condensed)` "
        "solver (else 0), `wall_s` the whole child process (its Python, imports and the "
        f"building of the {peer} problem included); the note gives {peer}'s own error."
    )
    files = report.write_table(out, "peers", table, title=title, intro=intro)
    summary = summarize(table, peer=peer, floor=floor)
    ratios = summary["ratio"].astype(float) if len(summary) else pd.Series(dtype=float)
    ratios = ratios[np.isfinite(ratios) & (ratios > 0)]
    mean = shifted_geometric_mean(ratios, shift=0.0) if len(ratios) else math.nan
    with_target = int(np.isfinite(summary["target"].astype(float)).sum()) if len(summary) else 0
    text = (
        f"{summary.shape[0]} files, {with_target} with a target; cocd reached it on "
        f"{len(ratios)}, faster than {peer} on {int((ratios < 1).sum())}. "
        + (
            f"Geometric mean of cocd / {peer} time to target: {mean:.3g}."
            if len(ratios)
            else "No ratio: no file where both sides reached the target."
        )
    )
    if peer_note:
        text += f" {peer_note}."
    bad = table[table["status"] == "unreadable"]
    if len(bad):
        text += " Unreadable: " + "; ".join(f"`{r.problem}` ({r.note})" for r in bad.itertuples())
    sum_intro = (
        f"Target: the best `natural_map_error` any {peer} solver reached on the file, at any "
        f"tolerance (at least {floor:g}). Time to target: the least `setup_s + solve_s` over "
        f"a side's runs whose error is at most the target (cocd: its conversion of the file, "
        f"the backend's set-up and solve; {peer}: the driver call, plus cocd's condensation "
        f"for a global problem solved condensed). `ratio`: cocd / {peer} (below 1: cocd is "
        "faster). `not reached`: no cocd run reached the target (the note gives cocd's best).\n\n"
        + text
    )
    shown_findings = findings(table, summary, peer=peer, floor=floor)
    if shown_findings:
        sum_intro += "\n\nComputed from the tables:\n\n" + "\n".join(
            f"- {line}" for line in shown_findings
        )
    files += report.write_table(
        out, "peers_summary", summary, title=f"{title}: time to target", intro=sum_intro
    )
    _, solvers, costs = profile_costs(table, summary) if len(summary) else ([], [], None)
    if costs is not None and costs.size and np.isfinite(costs).any():
        png = out / "peers_profile.png"
        _plot(png, solvers, costs, peer)
        files.append(png)
    else:
        text += " No profile: no file has a target."
    if len(summary):
        columns = ["problem", "nc", "target", "cocd_solver", "cocd_s"]
        shown = summary[[*columns, f"{peer}_solver", f"{peer}_s", "ratio"]]
        text += "\n\n" + shown.to_markdown(index=False, floatfmt=".3g")
    report.write_meta(out, "peers", title=title, files=files, summary=text)
    return files
