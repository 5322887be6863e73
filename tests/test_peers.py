"""Siconos beside cocd: one solve judged by cocd, the time limit, ``cocd bench peers``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import external
from typer.testing import CliRunner

from cocd.cli import app
from cocd.errors import CocdError
from cocd.io import read_problem
from cocd.peers import siconos

SMALL = ["NESpheres_10_1.dat", "fc2d_granularflowonwall_00667_00000.dat"]
runner = CliRunner()

needs_siconos = pytest.mark.skipif(
    siconos.peer_unavailable_reason() is not None,
    reason=str(siconos.peer_unavailable_reason()),
)


def small_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "problems"
    folder.mkdir()
    for name in SMALL:
        (folder / name).symlink_to(external(name))
    return folder


def one_line_error(result) -> None:
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    assert "Traceback" not in result.output


# -- one solve ------------------------------------------------------------------------
@needs_siconos
@pytest.mark.parametrize("name", SMALL)
def test_siconos_nsgs_answer_judged_by_cocd(name):
    problem = read_problem(external(name))
    record = siconos.solve(problem, "siconos:NSGS", 1e-10, time_limit=30)
    assert record["status"] == "optimal", record["note"]
    assert record["solver"] == "siconos:NSGS" and record["setup_s"] == 0.0
    assert record["solve_s"] < record["wall_s"] < 30
    r = record["r"].reshape(problem.nc, problem.dim)
    assert np.all(r[:, 0] >= 0)
    assert np.all(np.linalg.norm(r[:, 1:], axis=1) <= problem.mu * r[:, 0] * (1 + 1e-9) + 1e-14)
    error = problem.natural_map_error(record["r"])
    assert error == record["natural_map_error"] <= 1e-9
    # Siconos's own error is the same measure for NSGS: within a factor of 10 (or both
    # at the rounding of the data).
    own = record["peer_error"]
    assert max(error, own) <= 1e-14 or own / 10 <= error <= 10 * own, (error, own)


@needs_siconos
def test_a_global_problem_is_also_solved_condensed():
    problem = read_problem(external("GFC3D_TwoRods1.dat"))
    names = siconos.solvers_for(problem, ["NSGS", "NSGS(condensed)", "CPG"])
    assert names == ["siconos:NSGS", "siconos:NSGS(condensed)"]  # CPG is 2D only
    condensed = siconos.condense(problem)
    record = siconos.solve(problem, names[1], 1e-10, time_limit=30, condensed=condensed)
    assert record["status"] == "optimal" and record["natural_map_error"] <= 1e-9
    assert record["setup_s"] == condensed.seconds > 0  # cocd's condensation is charged
    with pytest.raises(CocdError, match="applies to global problems only"):
        siconos.solve(read_problem(external(SMALL[0])), "NSGS(condensed)", 1e-8)


@needs_siconos
def test_the_time_limit_stops_a_solve():
    problem = read_problem(external(SMALL[0]))
    # Hyperplane projection does not converge on this problem: it would run for hours.
    record = siconos.solve(problem, "HP", 1e-15, time_limit=0.5, max_iter=10**9)
    assert record["status"] == "time_limit", record["note"]
    assert record["r"] is None and np.isnan(record["natural_map_error"])
    assert record["wall_s"] < 20


def test_unknown_names_and_an_absent_siconos_are_one_line(monkeypatch):
    with pytest.raises(CocdError, match="unknown Siconos solver 'siconos:FOO'; known: "):
        siconos.parse("siconos:FOO")
    assert siconos.parse("siconos:nsn_ac(condensed)") == ("NSN_AC", True)
    monkeypatch.setenv(siconos.ENV, "/nonexistent")
    why = siconos.peer_unavailable_reason()
    assert why is not None and "\n" not in why
    assert "/nonexistent does not exist" in why and "apt-get install python3-siconos" in why


# -- the study ------------------------------------------------------------------------
@needs_siconos
def test_bench_peers_writes_tables_profile_and_resumes(tmp_path):
    folder = small_folder(tmp_path)
    out = tmp_path / "out"
    args = ["bench", "peers", str(folder), "--solvers", "nscd", "--peer-solvers", "NSGS"]
    args += ["--tols", "1e-6,1e-10", "--time-limit", "30", "--out", str(out)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    table = pd.read_csv(out / "peers.csv")
    assert len(table) == 8  # 2 files x (nscd + NSGS) x 2 tolerances
    assert set(table.side) == {"cocd", "siconos"}
    assert set(table.solver) == {"nscd", "siconos:NSGS"}
    assert (table.status == "optimal").all(), table[["problem", "solver", "status", "note"]]
    assert (table.setup_s >= 0).all() and (table.solve_s > 0).all()
    summary = pd.read_csv(out / "peers_summary.csv")
    assert sorted(summary.problem) == SMALL
    assert (summary.target > 0).all() and summary.siconos_solver.str.startswith("siconos:").all()
    text = (out / "peers_summary.md").read_text()
    assert "Geometric mean of cocd / siconos time to target" in text
    assert (out / "peers_profile.png").stat().st_size > 10_000
    assert "peers" in (out / "README.md").read_text()

    again = runner.invoke(app, [*args, "--resume"])
    assert again.exit_code == 0, again.output
    assert "8 rows kept" in again.output and "peers: 0 solves" in again.output
    pd.testing.assert_frame_equal(pd.read_csv(out / "peers.csv"), table)


def test_bench_peers_bad_options_are_one_line(tmp_path):
    folder = small_folder(tmp_path)
    out = str(tmp_path / "out")
    one_line_error(runner.invoke(app, ["bench", "peers", str(folder), "--tols", "0", "--out", out]))
    one_line_error(runner.invoke(app, ["bench", "peers", str(folder), "--peer", "x", "--out", out]))
    one_line_error(runner.invoke(app, ["bench", "peers", str(tmp_path / "none"), "--out", out]))
    one_line_error(
        runner.invoke(app, ["bench", "peers", str(folder), "--solvers", "nope", "--out", out])
    )
    if siconos.peer_unavailable_reason() is None:
        bad = ["bench", "peers", str(folder), "--peer-solvers", "FOO", "--out", out]
        one_line_error(runner.invoke(app, bad))


def test_bench_peers_without_siconos_runs_cocd_only(tmp_path, monkeypatch):
    folder = tmp_path / "problems"
    folder.mkdir()
    (folder / SMALL[0]).symlink_to(external(SMALL[0]))
    monkeypatch.setenv(siconos.ENV, "/nonexistent")
    out = tmp_path / "out"
    only_peer = ["bench", "peers", str(folder), "--solvers", "none", "--out", str(out)]
    result = runner.invoke(app, only_peer)
    one_line_error(result)
    assert "apt-get install python3-siconos" in result.output
    args = ["bench", "peers", str(folder), "--solvers", "nscd", "--tols", "1e-6"]
    result = runner.invoke(app, [*args, "--out", str(out)])
    assert result.exit_code == 0, result.output
    first = result.output.splitlines()[0]
    assert first.startswith("Siconos is not available: /nonexistent does not exist")
    assert first.endswith("running cocd's side only.") and "Traceback" not in result.output
    table = pd.read_csv(out / "peers.csv")
    assert table.side.tolist() == ["cocd"] and table.solver.tolist() == ["nscd"]
    # The local form stops on the error both sides are judged by.
    assert table.note.tolist() == ["local form"] and table.natural_map_error[0] <= 1e-6
    summary = pd.read_csv(out / "peers_summary.csv")
    assert summary.target.isna().all()
    assert "no siconos answer" in summary.note.iloc[0]


def test_bench_peers_solves_a_global_problem_condensed_with_newton(tmp_path, monkeypatch):
    name = "GFC3D_TwoRods1.dat"
    folder = tmp_path / "problems"
    folder.mkdir()
    (folder / name).symlink_to(external(name))
    monkeypatch.setenv(siconos.ENV, "/nonexistent")
    out = tmp_path / "out"
    args = ["bench", "peers", str(folder), "--solvers", "nscd:newton=True,clarabel"]
    result = runner.invoke(app, [*args, "--tols", "1e-12", "--out", str(out)])
    assert result.exit_code == 0, result.output
    table = pd.read_csv(out / "peers.csv").set_index("solver")
    assert table.loc["nscd:newton=True", "note"] == "local form (condensed)"
    assert table.loc["nscd:newton=True", "natural_map_error"] <= 1e-12
    assert table.loc["clarabel", "note"] != "local form (condensed)"


def test_findings_are_computed_from_the_table():
    """The summary's sentences carry the numbers of the rows: two files, cocd 2 and 8
    times slower to the peer's best (geometric mean 4), one of them worse than 3."""
    from cocd.studies._peers_report import findings, summarize

    rows = []
    for problem, cocd_s, peer_s in (("A-i1-2.dat", 0.2, 0.1), ("B-i3-4.hdf5", 0.8, 0.1)):
        common = {"problem": problem, "kind": "local", "dim": 3, "nc": 5, "tol": 1e-10}
        rows.append({**common, "side": "cocd", "solver": "nscd", "setup_s": 0.0,
                     "solve_s": cocd_s, "natural_map_error": 1e-13, "status": "optimal"})
        rows.append({**common, "side": "siconos", "solver": "siconos:NSGS", "setup_s": 0.0,
                     "solve_s": peer_s, "natural_map_error": 1e-11, "status": "optimal"})  # fmt: skip
    table = pd.DataFrame(rows)
    summary = summarize(table, peer="siconos", floor=1e-12)
    assert summary.ratio.round(6).tolist() == [2.0, 8.0]
    text = findings(table, summary, peer="siconos", floor=1e-12)
    assert text[0].startswith("cocd reaches siconos's best error (at least 1e-12) on 2 of 2")
    assert "geometric mean of cocd's time to it over siconos's is 4," in text[0]
    assert "from 2 (A-i1) to 8 (B-i3); 1 file is worse than 3 times: B-i3 8." in text[0]
    assert text[1] == "cocd's fastest solver to the target: `nscd` on 2."
    assert "geometric mean of cocd's least time over siconos's is 4." in text[2]
    assert text[3].endswith("A-i1 (1e-13 against 1e-11), B-i3 (1e-13 against 1e-11).")
