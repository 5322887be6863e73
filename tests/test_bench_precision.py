"""``cocd bench precision``: the profile and mean maths on constructed inputs, then tiny runs."""

from __future__ import annotations

import json
import math
from functools import partial

import numpy as np
import pandas as pd
import pytest
from conftest import run_study
from typer.testing import CliRunner

from cocd.bench.metrics import (
    costs_to_target,
    performance_profile,
    performance_ratios,
    sgm_table,
    shifted_geometric_mean,
)
from cocd.bench.runner import ROW_COLUMNS
from cocd.errors import CocdError
from cocd.studies import precision
from cocd.studies.precision import with_cold_runs_as_warm

INF = math.inf


# -- pure functions -----------------------------------------------------------
def test_shifted_geometric_mean_of_known_numbers():
    assert shifted_geometric_mean([1.0, 4.0, 16.0], shift=0.0) == pytest.approx(4.0)
    # (1 + 1)(3 + 1) = 8: sqrt(8) - 1.
    assert shifted_geometric_mean([1.0, 3.0], shift=1.0) == pytest.approx(math.sqrt(8.0) - 1.0)
    assert shifted_geometric_mean([2.5, 2.5, 2.5], shift=1.0) == pytest.approx(2.5)
    assert shifted_geometric_mean([0.0, 0.0], shift=1.0) == pytest.approx(0.0)
    assert shifted_geometric_mean([0.002]) == pytest.approx(0.002)  # one value: itself
    for bad in ([], [INF], [-1.0], [np.nan]):
        with pytest.raises(ValueError):
            shifted_geometric_mean(bad)


def test_performance_profile_with_one_solver_always_best():
    costs = np.array(
        [
            [1.0, 2.0, INF],
            [2.0, 2.0, 4.0],
            [3.0, 6.0, INF],
            [INF, INF, INF],  # nobody solved it: in the denominator, never counted
        ]
    )
    ratios = performance_ratios(costs)
    np.testing.assert_allclose(ratios[:3, 0], 1.0)
    np.testing.assert_allclose(ratios[:3, 1], [2.0, 1.0, 2.0])
    assert np.isinf(ratios[0, 2]) and ratios[1, 2] == pytest.approx(2.0)
    assert np.all(np.isinf(ratios[3]))

    taus = np.array([1.0, 1.5, 2.0, 1e6])
    profile = performance_profile(costs, taus)
    np.testing.assert_allclose(profile[:, 0], 0.75)  # every instance it can, at tau = 1
    np.testing.assert_allclose(profile[:, 1], [0.25, 0.25, 0.75, 0.75])
    np.testing.assert_allclose(profile[:, 2], [0.0, 0.0, 0.25, 0.25])

    solved_by_all = costs[:3, :2]
    assert performance_profile(solved_by_all, [1.0])[0, 0] == pytest.approx(1.0)


def test_performance_ratios_tie_at_zero_cost_and_reject_nan():
    np.testing.assert_allclose(performance_ratios([[0.0, 0.0, INF]])[0, :2], 1.0)
    with pytest.raises(ValueError):
        performance_ratios([[np.nan, 1.0]])
    with pytest.raises(ValueError):
        performance_ratios([1.0, 2.0])


def _rows(records):
    return pd.DataFrame(records, columns=["problem", "start", "solver", "wall_s", "ccp_residual"])


def test_costs_to_target_takes_the_fastest_run_that_reached_it():
    rows = _rows(
        [
            ("p", "cold", "a", 1.0, 1e-3),
            ("p", "cold", "a", 2.0, 1e-7),
            ("p", "cold", "a", 3.0, 1e-9),
            ("p", "cold", "b", 0.5, 1e-5),
            ("p", "cold", "b", 50.0, 1e-9),  # over the time limit: does not count
            ("p", "cold", "b", np.nan, np.nan),  # a failure
            ("p", "warm", "a", 0.1, np.nan),
        ]
    )
    instances = [("p", "cold"), ("p", "warm")]
    c4 = costs_to_target(rows, 1e-4, instances, ["a", "b"], time_limit=10.0)
    np.testing.assert_allclose(c4, [[2.0, 0.5], [INF, INF]])
    c8 = costs_to_target(rows, 1e-8, instances, ["a", "b"], time_limit=10.0)
    np.testing.assert_allclose(c8, [[3.0, INF], [INF, INF]])


def test_sgm_table_counts_unsolved_at_the_time_limit_and_normalises_to_the_best():
    costs = {1e-4: np.array([[1.0, 3.0], [1.0, INF]])}
    table = sgm_table(costs, ["a", "b"], time_limit=7.0, shift=1.0)
    assert list(table.columns) == ["target", "solver", "solved", "instances", "sgm_s", "sgm_rel"]
    a = table[table["solver"] == "a"].iloc[0]
    b = table[table["solver"] == "b"].iloc[0]
    assert a["sgm_s"] == pytest.approx(1.0) and a["sgm_rel"] == pytest.approx(1.0)
    # b: 3 s and the 7 s time limit: sqrt(4 * 8) - 1.
    assert b["sgm_s"] == pytest.approx(math.sqrt(32.0) - 1.0)
    assert b["sgm_rel"] == pytest.approx(math.sqrt(32.0) - 1.0)
    assert (a["solved"], b["solved"], a["instances"]) == (2, 1, 2)
    assert table.iloc[0]["solver"] == "a"
    nobody = sgm_table({1e-8: np.full((2, 2), INF)}, ["a", "b"], time_limit=7.0)
    assert np.allclose(nobody["sgm_s"], 7.0) and nobody["sgm_rel"].isna().all()


def test_cold_runs_stand_for_backends_without_a_warm_start():
    rows = pd.DataFrame(
        {"start": ["cold", "cold", "warm"], "solver": ["ipm", "fo", "fo"], "wall_s": [1, 2, 3]}
    )
    out = with_cold_runs_as_warm(rows, {"fo"})
    warm = out[out["start"] == "warm"]
    assert sorted(warm["solver"]) == ["fo", "ipm"] and len(out) == 4


# -- runs ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    with pytest.MonkeyPatch.context() as mp:
        path = tmp_path_factory.mktemp("cocd-cache")
        mp.setenv("COCD_CACHE", str(path))
        yield path


@pytest.fixture(scope="module")
def tiny_run(cache, tmp_path_factory):
    out = tmp_path_factory.mktemp("precision")
    settings = dict(solvers="clarabel,scs-dual", tols=[1e-8, 1e-3], n2d=30, n3d=20)
    return run_study(precision.STUDY, out, time_limit=60.0, **settings)


def test_run_writes_every_file_with_the_stated_columns(tiny_run):
    out, table, lines = tiny_run
    for name in (
        "precision.csv",
        "precision_column-2d.png",
        "precision_box-3d.png",
        "precision_profile.png",
        "precision_sgm.csv",
        "precision_sgm.md",
        "precision.meta.json",
    ):
        assert (out / name).is_file(), name
    csv = pd.read_csv(out / "precision.csv")
    expected = ["problem", "dim", "N", "Nc", "start", "solver", "tol", *ROW_COLUMNS]
    assert set(expected) <= set(csv.columns)
    assert len(csv) == len(table)
    # clarabel has no warm start: cold only; scs-dual both. 2 problems x 2 tolerances.
    counts = csv.groupby(["solver", "start"]).size().to_dict()
    assert counts == {("clarabel", "cold"): 4, ("scs-dual", "cold"): 4, ("scs-dual", "warm"): 4}
    assert set(csv["problem"]) == {"column-2d", "box-3d"}
    assert set(csv.loc[csv["problem"] == "box-3d", "dim"]) == {3}
    assert (csv["N"] > 0).all() and (csv["Nc"] > 0).all()

    sgm = pd.read_csv(out / "precision_sgm.csv")
    columns = ["problems", "target", "solver", "solved", "instances", "sgm_s", "sgm_rel"]
    assert list(sgm.columns) == columns
    assert sorted(set(sgm["target"])) == [1e-8, 1e-6, 1e-4]
    # Over both problems x cold/warm, then over each dimension's two instances.
    instances = sgm.groupby("problems")["instances"].unique().to_dict()
    assert {k: list(v) for k, v in instances.items()} == {"all": [4], "2D": [2], "3D": [2]}
    assert len(sgm) == 3 * 3 * 2
    for _, group in sgm.groupby(["problems", "target"]):
        if (group["solved"] > 0).any():
            assert group["sgm_rel"].min() == pytest.approx(1.0)
    md = (out / "precision_sgm.md").read_text()
    assert "shift 1 s" in md and "time limit" in md
    meta = json.loads((out / "precision.meta.json").read_text())
    assert meta["name"] == "precision" and "sgm_rel" in meta["summary"]
    assert "precision_profile.png" in meta["files"]
    assert any("reference" in line for line in lines)
    assert any(line.startswith("[1/") for line in lines)


def test_clarabel_reaches_tight_tolerances_and_error_falls(tiny_run):
    _, table, _ = tiny_run
    clarabel = table[table["solver"] == "clarabel"]
    assert set(clarabel["status"]) <= {"optimal", "inaccurate"}
    for problem, runs in clarabel.groupby("problem"):
        tight = runs[runs["tol"] == 1e-8].iloc[0]
        loose = runs[runs["tol"] == 1e-3].iloc[0]
        assert tight["ccp_residual"] <= 1e-7, problem
        assert tight["u_error"] < 1e-5, problem
        # Tightening does not make it worse (beyond rounding at the floor).
        assert tight["ccp_residual"] <= max(10 * loose["ccp_residual"], 1e-12), problem
    scs = table[(table["solver"] == "scs-dual") & (table["status"] == "optimal")]
    assert (scs["wall_s"] > 0).all() and np.isfinite(scs["u_error"]).all()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"tols": []}, "tols is empty"),
        ({"tols": [1e-3, 0.0]}, "finite and > 0"),
        ({"tols": [-1e-3]}, "finite and > 0"),
        ({"tols": [float("nan")]}, "finite and > 0"),
        ({"n2d": 0, "n3d": 0}, "both 0"),
        ({"n2d": -5}, "n2d must be an integer >= 0"),
        ({"n3d": -1}, "n3d must be an integer >= 0"),
        ({"time_limit": 0.0}, "--time-limit must be a finite number > 0"),
        ({"solvers": "no-such-solver"}, "no-such-solver"),
    ],
)
def test_bad_input_raises_cocd_error(tmp_path, kwargs, message):
    args = dict(
        solvers="clarabel",
        tols=[1e-4],
        n2d=10,
        n3d=0,
        time_limit=10.0,
        memory_gb=None,
        out=tmp_path,
        progress=lambda _line: None,
    )
    args.update(kwargs)
    with pytest.raises(CocdError, match=message):
        precision.STUDY(**args)  # type: ignore[arg-type]
    assert not (tmp_path / "precision.csv").exists()


def test_cli_runs_the_command(cache, tmp_path):
    from cocd.cli import app

    args = ["bench", "precision", "--n2d", "30", "--n3d", "0", "--solvers", "clarabel"]
    args += ["--tols", "1e-4,1e-8", "--out", str(tmp_path)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    csv = pd.read_csv(tmp_path / "precision.csv")
    assert list(csv["tol"]) == [1e-4, 1e-8] and set(csv["solver"]) == {"clarabel"}
    assert (tmp_path / "README.md").is_file()
    # --resume keeps clarabel's rows as they are and solves only the new backend's.
    more = [a if a != "clarabel" else "clarabel,scs-dual" for a in args]
    again = CliRunner().invoke(app, [*more, "--resume"])
    assert again.exit_code == 0, again.output
    assert again.output.count("(kept from the earlier table)") == 2
    after = pd.read_csv(tmp_path / "precision.csv")
    mine = after[after.solver == "clarabel"].reset_index(drop=True)
    assert list(mine.wall_s) == list(csv.wall_s) and len(after) == 2 + 4  # scs: cold, warm
    assert (after[after.solver == "scs-dual"].ccp_residual <= 1e-3).all()
    bad = CliRunner().invoke(app, ["bench", "precision", "--n2d", "0", "--n3d", "0"])
    assert bad.exit_code == 2 and "both 0" in bad.output


def test_reference_falls_back_when_clarabel_is_not_accurate_enough(cache, monkeypatch):
    import solvers
    from cocd.bench.states import record_steps
    from cocd.builders import stack

    # Grains resting on each other: every contact carries weight.
    seq = record_steps("stack", partial(stack, 5, dim=2), dt=1e-3, t_start=0.0, n_steps=1)
    problem = seq.problems[0]
    real_solve = solvers.solve

    def worse_clarabel(problem, solver="clarabel", tol=1e-8, *args, **kwargs):
        sol = real_solve(problem, solver, tol, *args, **kwargs)
        if solver == "clarabel":
            sol.p = sol.p * 1.01  # a 1 % error: far above the reference's 1e-9
        return sol

    monkeypatch.setattr(solvers, "solve", worse_clarabel)
    lines: list[str] = []
    ref = precision._reference(problem, "tiny", lines.append)
    assert ref.solver == "clarabel-dual" and ref.ccp <= precision.REFERENCE_OK
    assert any("reference clarabel " in line for line in lines)


def test_a_time_out_skips_the_tighter_tolerances(cache, tmp_path):
    # No solve of a 30-disc problem fits in 0.1 ms: the first run is over the
    # limit, so the tighter one is not attempted.
    table = precision.STUDY(
        solvers="clarabel",
        tols=[1e-8, 1e-3],
        n2d=30,
        n3d=0,
        time_limit=1e-4,
        out=tmp_path,
        progress=lambda _line: None,
    )
    assert list(table["tol"]) == [1e-3, 1e-8]
    assert table.iloc[1]["status"] == "skipped"
    assert "timed out at tol 0.001" in table.iloc[1]["note"]
    sgm = pd.read_csv(tmp_path / "precision_sgm.csv")
    assert (sgm["solved"] == 0).all() and np.allclose(sgm["sgm_s"], 1e-4)
    assert sgm["sgm_rel"].isna().all()


def test_sgm_per_dimension_does_not_charge_a_2d_only_backend_for_3d():
    from types import SimpleNamespace

    insts = [SimpleNamespace(label="p2", dim=2), SimpleNamespace(label="p3", dim=3)]
    chosen = {"p2": ["ipm", "qp"], "p3": ["ipm"]}
    rows = pd.DataFrame(
        [
            (p, s, solver, t, 1e-9)
            for p, solver, t in [("p2", "ipm", 2.0), ("p2", "qp", 0.5), ("p3", "ipm", 3.0)]
            for s in ("cold", "warm")
        ],
        columns=["problem", "start", "solver", "wall_s", "ccp_residual"],
    )
    table = precision._sgm_by_problems(rows, insts, chosen, ["ipm", "qp"], time_limit=100.0)
    two = table[(table.problems == "2D") & (table.target == 1e-8)].set_index("solver")
    assert two.loc["qp", "sgm_rel"] == pytest.approx(1.0)
    assert two.loc["ipm", "sgm_rel"] == pytest.approx(2.0 / 0.5)
    three = table[(table.problems == "3D") & (table.target == 1e-8)]
    assert list(three.solver) == ["ipm"] and three.sgm_rel.iloc[0] == pytest.approx(1.0)
    # Over all instances, qp is charged the time limit where it cannot go.
    every = table[(table.problems == "all") & (table.target == 1e-8)].set_index("solver")
    assert every.loc["qp", "solved"] == 2 and every.loc["qp", "instances"] == 4
    assert every.loc["qp", "sgm_rel"] > 1.0
