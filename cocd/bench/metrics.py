"""The harness's statistics: shifted geometric means, Dolan-Moré performance
profiles and power-law fits, shared by every study.

Pure functions of numbers and tables; they read and write no files.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from cocd.errors import CocdError

__all__ = [
    "SGM_SHIFT",
    "costs_to_target",
    "finite",
    "finite_max",
    "finite_mean",
    "fit_exponent",
    "fit_two_power_laws",
    "performance_profile",
    "performance_ratios",
    "sgm_table",
    "shifted_geometric_mean",
    "table_profile",
]

FloatArray = NDArray[np.float64]

#: Shift (seconds) of the geometric means: times well under a second weigh
#: as little as they matter to a user, so a 1 ms against 2 ms gap does not
#: count like a 100 s against 200 s one.
SGM_SHIFT = 1.0


def shifted_geometric_mean(times: ArrayLike, shift: float = SGM_SHIFT) -> float:
    """``exp(mean(log(t + shift))) - shift`` of non-negative finite times.

    Parameters
    ----------
    times : array_like
        Seconds, at least one.
    shift : float
        Seconds added before the logarithm (and removed after); ``0`` gives
        the plain geometric mean.

    Returns
    -------
    float
    """
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if t.size == 0:
        raise ValueError("shifted_geometric_mean of no times")
    if not (np.all(np.isfinite(t)) and np.all(t >= 0.0)):
        raise ValueError(f"times must be finite and >= 0, got {t}")
    if not shift >= 0.0:
        raise ValueError(f"shift must be >= 0, got {shift}")
    return float(np.exp(np.mean(np.log(t + shift))) - shift)


def performance_ratios(costs: ArrayLike) -> FloatArray:
    """Dolan-Moré ratios ``r[i, s] = costs[i, s] / min_s costs[i, s]``.

    Parameters
    ----------
    costs : (n_instances, n_solvers) array_like
        Cost of each solver on each instance, ``inf`` when it did not solve it.

    Returns
    -------
    (n_instances, n_solvers) array
        ``inf`` where the solver did not solve the instance (and on every
        solver of an instance no one solved).
    """
    c = np.asarray(costs, dtype=np.float64)
    if c.ndim != 2:
        raise ValueError(f"costs must be (instances, solvers), got shape {c.shape}")
    if np.any(np.isnan(c)) or np.any(c < 0.0):
        raise ValueError("costs must be >= 0 (inf for unsolved), not NaN")
    best = c.min(axis=1, initial=np.inf, keepdims=True)
    ratios = np.full(c.shape, np.inf)
    solved = np.isfinite(c)
    # A zero best cost (an instance every solver answers instantly) makes every
    # solver that solved it tie at 1, rather than 0/0; an instance nobody solved
    # (best = inf) has no solved entry to divide.
    positive = np.isfinite(best) & (best > 0.0)
    safe = np.where(positive, best, 1.0)
    ratios[solved] = np.where(positive, c / safe, 1.0)[solved]
    return ratios


def performance_profile(costs: ArrayLike, taus: ArrayLike) -> FloatArray:
    """Fraction of instances each solver solves within ``tau`` times the best cost.

    Parameters
    ----------
    costs : (n_instances, n_solvers) array_like
        As :func:`performance_ratios`; unsolved (``inf``) never counts.
    taus : (n_taus,) array_like
        Ratios ``>= 1`` at which to evaluate.

    Returns
    -------
    (n_taus, n_solvers) array
        ``rho_s(tau) = #{i : r[i, s] <= tau} / n_instances``.
    """
    r = performance_ratios(costs)
    t = np.asarray(taus, dtype=np.float64).reshape(-1)
    if r.shape[0] == 0:
        return np.zeros((t.size, r.shape[1]))
    return np.asarray((r[None, :, :] <= t[:, None, None]).mean(axis=1), dtype=np.float64)


def table_profile(
    table: pd.DataFrame, solved: pd.Series, taus: np.ndarray
) -> dict[str, np.ndarray]:
    """Dolan-Moré profile: for each solver, the fraction of problems solved within
    ``tau`` times the fastest time on that problem.

    ``solved`` marks the rows that count; the problems are those any solver solved
    (a problem nobody solves says nothing about relative speed).
    """
    t = table.assign(t=np.where(solved, table["wall_s"], np.inf))
    times = t.pivot_table(index="problem", columns="solver", values="t", aggfunc="min")
    times = times.replace(np.nan, np.inf)
    times = times[np.isfinite(times.min(axis=1))]
    fractions = performance_profile(times.to_numpy(dtype=np.float64), taus)
    return {str(solver): fractions[:, k] for k, solver in enumerate(times.columns)}


def fit_exponent(n: Any, t: Any) -> tuple[float, float]:
    """``(k, c)`` of ``t = c n^k`` by least squares on logarithms (NaN with < 2 points)."""
    n = np.asarray(n, dtype=float)
    t = np.asarray(t, dtype=float)
    ok = np.isfinite(t) & (t > 0) & (n > 0)
    if ok.sum() < 2:
        return float("nan"), float("nan")
    k, logc = np.polyfit(np.log(n[ok]), np.log(t[ok]), 1)
    return float(k), float(math.exp(logc))


def fit_two_power_laws(
    a: Sequence[float], y: Sequence[float], *, min_points: int = 3
) -> dict[str, float]:
    """Fit ``y = c1 a^k1`` below a split ``a_c`` and ``y = c2 a^k2`` above it.

    The split is placed between two consecutive distinct ``a`` (at their geometric
    mean) where the summed squared residuals of ``log y`` are least, each side having
    at least ``min_points`` distinct ``a``. Several ``y`` per ``a`` (packings) are
    fitted as they are. Returns ``a_c``, ``k_low``, ``c_low``, ``k_high``, ``c_high``
    and ``k_all``, ``c_all`` (one law through every point), and for each exponent
    ``k_*_ci``, the half-width of its 95 % confidence interval (Student's t on the
    slope's standard error; NaN for two points). NaN where a side has too few points.
    The intervals take the points as independent and the split as given, not chosen
    from them: they are a lower bound on the uncertainty. ``p_two_laws`` is the F-test's
    p-value of the two laws against the one (F ratio of the residuals, its null
    distribution drawn with the split searched afresh, so choosing the split from the
    data is accounted for): small when the bend is real, large when the data do not
    tell two regimes from one.
    """
    av = np.asarray(a, dtype=float)
    yv = np.asarray(y, dtype=float)
    good = av.shape == yv.shape and av.size >= 2
    good = good and bool(np.all(np.isfinite(av) & (av > 0) & np.isfinite(yv) & (yv > 0)))
    if not good:
        raise CocdError("power-law fits need at least two positive, finite (a, y) pairs")
    x, z = np.log(av), np.log(yv)
    if np.unique(x).size < 2:
        raise CocdError("power-law fits need at least two distinct a")
    order = np.argsort(x, kind="stable")
    x, z = x[order], z[order]
    k_all, c_all, ci_all = _line(x, z)
    out = {"k_all": k_all, "c_all": math.exp(c_all), "k_all_ci": ci_all}
    distinct = np.unique(x)
    best: tuple[float, float] | None = None
    for j in range(min_points, distinct.size - min_points + 1):
        cut = 0.5 * (distinct[j - 1] + distinct[j])
        low = x < cut
        cost = 0.0
        for part in (low, ~low):
            coef = np.polyfit(x[part], z[part], 1)
            cost += float(np.sum((np.polyval(coef, x[part]) - z[part]) ** 2))
        if best is None or cost < best[0]:
            best = (cost, cut)
    if best is None:
        out.update(
            a_c=math.nan, k_low=math.nan, c_low=math.nan, k_high=math.nan, c_high=math.nan,
            k_low_ci=math.nan, k_high_ci=math.nan, p_two_laws=math.nan,
        )  # fmt: skip
        return out
    low = x < best[1]
    k1, c1, ci1 = _line(x[low], z[low])
    k2, c2, ci2 = _line(x[~low], z[~low])
    out.update(
        a_c=float(math.exp(best[1])),
        k_low=k1,
        c_low=math.exp(c1),
        k_high=k2,
        c_high=math.exp(c2),
        k_low_ci=ci1,
        k_high_ci=ci2,
        p_two_laws=_f_test(x, z, min_points),
    )
    return out


#: Bootstrap draws of the two-law test: its smallest p-value is 1 / (1 + BEND_DRAWS).
BEND_DRAWS = 999


def _f_test(x: np.ndarray, z: np.ndarray, min_points: int, draws: int = BEND_DRAWS) -> float:
    """p-value of the best two-line split against one line (``x`` sorted).

    The statistic is the F ratio of the residuals; its null distribution is drawn by a
    parametric bootstrap (one line plus Gaussian scatter of the fitted size, the split
    searched afresh each time), so that choosing the split from the data is accounted
    for. Fixed random seed: the same data give the same p.
    """

    distinct = np.unique(x)
    cuts = [
        0.5 * (distinct[j - 1] + distinct[j])
        for j in range(min_points, distinct.size - min_points + 1)
    ]
    dof = x.size - 4
    if not cuts or dof <= 0:
        return math.nan

    def residual_maker(mask: np.ndarray) -> np.ndarray:
        """I - H for the least-squares line through the points of ``mask``."""
        design = np.column_stack([np.ones(int(mask.sum())), x[mask]])
        return np.eye(design.shape[0]) - design @ np.linalg.pinv(design)

    whole = residual_maker(np.ones(x.size, dtype=bool))
    parts = [(x < c, residual_maker(x < c), residual_maker(x >= c)) for c in cuts]

    def statistic(zs: np.ndarray) -> np.ndarray:
        """F ratio of the best split, for each row of ``zs``."""
        one = np.sum((zs @ whole) ** 2, axis=1)
        two = np.min(
            [
                np.sum((zs[:, low] @ m_low) ** 2, axis=1)
                + np.sum((zs[:, ~low] @ m_high) ** 2, axis=1)
                for low, m_low, m_high in parts
            ],
            axis=0,
        )
        return ((one - two) / 2.0) / np.maximum(two / dof, 1e-300)

    one = float(np.sum((z @ whole) ** 2))
    if one <= 1e-24 * max(1.0, float(np.sum((z - z.mean()) ** 2))):
        return 1.0  # one law fits to rounding: nothing for a second to explain
    observed = float(statistic(z[None, :])[0])
    sigma = math.sqrt(one / (x.size - 2))
    line = z - z @ whole  # the fitted line's values
    rng = np.random.default_rng(0)
    null = statistic(line + rng.normal(0.0, sigma, (draws, x.size)))
    return float((1 + np.sum(null >= observed)) / (1 + draws))


def _line(x: np.ndarray, z: np.ndarray) -> tuple[float, float, float]:
    """Least-squares slope, intercept and the 95 % half-width of the slope."""
    from scipy import stats

    fit = stats.linregress(x, z)
    dof = x.size - 2
    ci = float(stats.t.ppf(0.975, dof) * fit.stderr) if dof > 0 else math.nan
    return float(fit.slope), float(fit.intercept), ci


def finite(value: object) -> bool:
    """Whether ``value`` is a finite number (None, text and NaN are not)."""
    try:
        return math.isfinite(float(value))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False


def finite_mean(rows: Sequence[Mapping[str, Any]], key: str) -> float:
    """The mean of ``row[key]`` over the rows where it is a finite number (NaN if none)."""
    values = [float(r[key]) for r in rows if finite(r.get(key))]
    return float(np.mean(values)) if values else math.nan


def finite_max(rows: Sequence[Mapping[str, Any]], key: str) -> float:
    """The largest ``row[key]`` over the rows where it is a finite number (NaN if none)."""
    values = [float(r[key]) for r in rows if finite(r.get(key))]
    return max(values) if values else math.nan


def costs_to_target(
    rows: pd.DataFrame,
    target: float,
    instances: Sequence[tuple[str, str]],
    solver_names: Sequence[str],
    time_limit: float,
) -> FloatArray:
    """Cost of each solver on each instance: its fastest run that reached ``target``.

    Parameters
    ----------
    rows : DataFrame
        Runs with columns ``problem``, ``start``, ``solver``, ``wall_s`` and
        ``ccp_residual``.
    target : float
        A run reaches it when ``ccp_residual <= target``.
    instances : sequence of (problem, start)
    solver_names : sequence of str
    time_limit : float
        A run longer than this does not count (it would have been stopped).

    Returns
    -------
    (n_instances, n_solvers) array
        Smallest ``wall_s`` among the runs that reached the target, ``inf``
        when none did.
    """
    costs = np.full((len(instances), len(solver_names)), np.inf)
    ok = (rows["ccp_residual"] <= target) & (rows["wall_s"] <= time_limit)
    good = rows[ok]
    best = good.groupby(["problem", "start", "solver"])["wall_s"].min()
    for i, (problem, start) in enumerate(instances):
        for s, name in enumerate(solver_names):
            key = (problem, start, name)
            if key in best.index:
                costs[i, s] = float(best[key])
    return costs


def sgm_table(
    costs: dict[float, FloatArray],
    solver_names: Sequence[str],
    time_limit: float,
    shift: float = SGM_SHIFT,
) -> pd.DataFrame:
    """Shifted geometric mean of the time to reach each target, per solver.

    Parameters
    ----------
    costs : dict target -> (n_instances, n_solvers) array
        From :func:`costs_to_target`; ``inf`` (not reached) counts as
        ``time_limit``.
    solver_names : sequence of str
    time_limit : float
    shift : float

    Returns
    -------
    DataFrame
        Columns ``target``, ``solver``, ``solved`` (instances that reached the
        target), ``instances``, ``sgm_s`` (seconds) and ``sgm_rel`` (over the
        best solver's ``sgm_s`` for that target, so the best is 1.0); sorted by
        target (loosest first) then ``sgm_rel``. ``sgm_rel`` is NaN for a
        target no solver reached on any instance.
    """
    records: list[dict[str, Any]] = []
    for target, c in costs.items():
        charged = np.where(np.isfinite(c), c, time_limit)
        means = [shifted_geometric_mean(charged[:, s], shift) for s in range(len(solver_names))]
        # With no instance reached by anyone every mean is the time limit:
        # a ratio of 1.0 would read as a tie of winners, not of failures.
        anyone = bool(np.isfinite(c).any())
        best = min(means, default=np.nan) if anyone else np.nan
        for s, name in enumerate(solver_names):
            records.append(
                {
                    "target": target,
                    "solver": name,
                    "solved": int(np.isfinite(c[:, s]).sum()),
                    "instances": int(c.shape[0]),
                    "sgm_s": means[s],
                    "sgm_rel": means[s] / best if best > 0 else (1.0 if anyone else np.nan),
                }
            )
    table = pd.DataFrame(
        records, columns=["target", "solver", "solved", "instances", "sgm_s", "sgm_rel"]
    )
    return table.sort_values(["target", "sgm_rel"], ascending=[False, True], kind="stable")
