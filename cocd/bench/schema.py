"""The one result schema: every study's table names the same quantity the same way.

A row is one backend on one problem (a problem file, a recorded step) or on a
sequence of step problems; in the second case its numbers are over the
sequence's solves (means of times and iterations, maxima of residuals), and
the study's README says which. Tables written by earlier versions used other
names (:data:`RENAMED`); :func:`upgrade` reads them under the current ones, so
that they can be resumed, and ``cocd bench upgrade DIR`` rewrites them.
"""

from __future__ import annotations

import pandas as pd

__all__ = ["COLUMNS", "RENAMED", "SOLVE_COLUMNS", "markdown", "upgrade"]

#: The shared columns, in the order a table lists them, with their meaning.
COLUMNS: dict[str, str] = {
    "problem": "what was solved: a problem file, or a named step problem or sequence",
    "dim": "2 or 3",
    "N": "free grains",
    "Nc": "potential contacts (mean over a sequence)",
    "dt": "time step (s)",
    "solver": "backend, as `cocd solvers` names it",
    "tol": "tolerance asked of the backend (its stopping test is the framework's residual)",
    "formulation": "the form the backend solved (primal, dual, ccp, local)",
    "start": "`cold`, or `warm`: started from the previous step's impulses",
    "status": "optimal, inaccurate, max_iter, time_limit, infeasible, error, or why not run",
    "steps_ok": "optimal solves / solves asked, for a sequence",
    "iterations": "the backend's iterations (mean over a sequence)",
    "setup_s": "seconds building the backend's problem, in the backend",
    "solve_s": "seconds in the backend's solve",
    "wall_s": "seconds from the call to the answer, set-up included (mean over a sequence)",
    "ccp_residual": "`cocd.residuals.ccp_residual` of the answer (largest over a sequence)",
    "coulomb_residual": "`cocd.residuals.coulomb_residual` (largest over a sequence)",
    "natural_map_error": "`cocd.residuals.natural_map_error`, on a problem file's own W and q",
    "u_error": "largest velocity difference from a reference answer (m/s)",
    "note": "what went wrong, or how the row was made",
}

#: What every row of one solve says, in this order.
SOLVE_COLUMNS = [
    "status",
    "iterations",
    "setup_s",
    "solve_s",
    "wall_s",
    "ccp_residual",
    "coulomb_residual",
]

#: Names used by earlier versions, and the names that replaced them.
RENAMED: dict[str, str] = {
    "backend": "solver",
    "eps": "tol",
    "time_s": "solve_s",
    "time_per_step_s": "wall_s",
    "mean_time_per_step_s": "solve_s",
    "mean_iterations": "iterations",
    "max_ccp_residual": "ccp_residual",
    "warm": "start",
}

#: ``warm``'s values, as ``start`` says them.
_WARM_AS_START = {"yes": "warm", "no": "cold"}


def upgrade(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` under the current names (a copy; unchanged when it already uses them).

    A column is renamed only when its new name is not there already; ``warm``'s
    ``yes``/``no`` become ``start``'s ``warm``/``cold``.
    """
    renames = {
        old: new
        for old, new in RENAMED.items()
        if old in table.columns and new not in table.columns
    }
    if not renames:
        return table
    table = table.rename(columns=renames)
    if renames.get("warm") == "start":
        table["start"] = table["start"].map(lambda v: _WARM_AS_START.get(v, v))
    return table


def markdown() -> str:
    """The schema as a Markdown table (for the results README)."""
    lines = ["| column | meaning |", "|---|---|"]
    lines += [f"| `{name}` | {meaning} |" for name, meaning in COLUMNS.items()]
    return "\n".join(lines)
