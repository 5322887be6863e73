"""``cocd bench scaling`` on tiny sizes: rows, fits, files."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from cocd.bench import metrics
from cocd.cli import app
from cocd.errors import CocdError
from cocd.studies import scaling


@pytest.fixture
def cache(tmp_path, monkeypatch):
    path = tmp_path / "cache"
    monkeypatch.setenv("COCD_CACHE", str(path))
    return path


def test_fit_exponent_recovers_a_power_law():
    n = np.array([100, 1000, 10000])
    k, c = metrics.fit_exponent(n, 3e-4 * n**1.4)
    assert k == pytest.approx(1.4) and c == pytest.approx(3e-4)
    assert np.isnan(metrics.fit_exponent([100], [1.0])[0])


def test_scaling_tiny_run(tmp_path, cache, monkeypatch):
    monkeypatch.setattr(scaling, "T_START_2D", 0.005)
    out = tmp_path / "results"
    table = scaling.STUDY(
        solvers="ipm,clarabel",
        n2d=[30, 60],
        n3d=[8, 27],
        steps=2,
        time_limit=60.0,
        out=out,
        trajectory="clarabel",
        progress=lambda line: None,
        packings=["jammed_box"],
    )
    assert len(table) == 8
    assert set(table.solver) == {"ipm", "clarabel"}
    assert set(table.packing) == {"column", "jammed_box"}
    assert (table.start == "cold").all()
    assert (table.steps_ok == "2/2").all()
    assert (table.ccp_residual[table.dim == 2] <= 1e-8).all()
    assert (table.ccp_residual[table.dim == 3] <= 1e-5).all()
    assert (table.detect_assemble_s[table.dim == 3] > 0).all()
    solved = table[table.dim == 3]
    assert ((solved.peak_rss_gib > 0.05) & (solved.peak_rss_gib < 8)).all()
    fits = pd.read_csv(out / "scaling.csv")
    assert len(fits) == 8
    text = (out / "scaling_fit.md").read_text()
    assert "exponent" in text and "ipm" in text
    assert (out / "scaling.png").stat().st_size > 5000
    with pytest.raises(CocdError, match="steps must be >= 1"):
        scaling.STUDY(
            solvers="ipm", n2d=[30], n3d=[], steps=0, time_limit=1.0, out=out
        )


def test_scaling_real_packings_have_granular_contact_counts(tmp_path, cache):
    # The seed's column mid-flow (warm-started for apgd) and a rain-deposited box at
    # rest have the potential contacts of a random packing (over 5 per sphere, walls
    # included, at 60 spheres), the cubic lattice about half as many.
    table = scaling.STUDY(
        solvers="apgd,ipm",
        n2d=[],
        n3d=[60],
        steps=1,
        time_limit=120.0,
        out=tmp_path,
        progress=lambda line: None,
    )
    assert list(table.packing.unique()) == ["column", "box", "jammed_box"]
    assert (table.steps_ok == "1/1").all()
    assert (table.ccp_residual <= 1e-5).all()
    by = table.set_index(["packing", "solver"])
    assert by.loc[("column", "apgd"), "start"] == "warm"
    assert by.loc[("column", "ipm"), "start"] == "cold"
    assert by.loc[("box", "apgd"), "start"] == "cold"
    lattice = by.loc[("jammed_box", "apgd"), "Nc_per_grain"]
    assert lattice < 3.6
    assert by.loc[("box", "apgd"), "Nc_per_grain"] > 5.0
    assert by.loc[("column", "apgd"), "Nc_per_grain"] > 5.0
    fitted = scaling.fits(table)
    assert set(zip(fitted.packing, fitted.solver, strict=True)) == {
        (p, s) for p in ("column", "box", "jammed_box") for s in ("apgd", "ipm")
    }
    with pytest.raises(CocdError, match="unknown 3D packing 'rain'"):
        scaling.STUDY(solvers="apgd", n2d=[], n3d=[8], steps=1, time_limit=1.0,
                    out=tmp_path, packings=["rain"])  # fmt: skip


def test_scaling_skips_larger_sizes_after_a_time_limit(tmp_path):
    # A time limit no backend can meet: apgd stops on it at the first size and
    # is not tried at the next one.
    table = scaling.STUDY(
        solvers="apgd",
        n2d=[],
        n3d=[8, 27],
        steps=1,
        time_limit=1e-9,
        out=tmp_path,
        progress=lambda line: None,
        packings=["jammed_box"],
    )
    assert list(table.N) == [8, 27]
    first, second = table.iloc[0], table.iloc[1]
    assert first.steps_ok == "0/1" and "time_limit" in first.note
    assert second.steps_ok == "0/1" and second.note == "skipped: time limit at N = 8"
    assert np.isnan(second.wall_s)


def test_scaling_cli_rejects_bad_sizes(tmp_path):
    result = CliRunner().invoke(app, ["bench", "scaling", "--n2d", "10,x", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "--n2d must be comma-separated integers" in result.output


def test_scaling_takes_2d_rows_from_table1(tmp_path, cache):
    rows = [
        dict(
            source="this machine",
            dim=2,
            N=n,
            Nc=3.0 * n,
            Nc_per_grain=3.0,
            solver="ipm",
            start="cold",
            tol=1e-8,
            steps_ok="10/10",
            iterations=20.0,
            wall_s=1e-4 * n**1.2,
            ccp_residual=1e-9,
            note="",
        )
        for n in (1000, 8000)
    ] + [
        dict(
            source="seed (Mosek, 2x8 cores)",
            dim=2,
            N=8308,
            Nc=37331.0,
            Nc_per_grain=4.49,
            solver="mosek",
            start="cold",
            tol=1e-8,
            steps_ok="",
            iterations=47.0,
            wall_s=8.85,
            ccp_residual=None,
            note="",
        )
    ]
    path = tmp_path / "table1.csv"
    pd.DataFrame(rows).to_csv(path, index=False)
    table = scaling.STUDY(
        solvers="ipm",
        n2d=[],
        n3d=[8],
        steps=1,
        time_limit=60.0,
        out=tmp_path / "out",
        table1=path,
        progress=lambda line: None,
        packings=["jammed_box"],
    )
    two = table[table.dim == 2]
    assert list(two.N) == [1000, 8000] and (two.note.str.startswith("from table1.csv")).all()
    fit = scaling.fits(table)
    k = fit[(fit.dim == 2) & (fit.solver == "ipm")].exponent.iloc[0]
    assert k == pytest.approx(1.2)


def test_scaling_cli_rejects_an_unknown_packing_in_one_line(tmp_path):
    args = ["bench", "scaling", "--n2d", "", "--n3d", "8", "--packings", "column,rain"]
    result = CliRunner().invoke(app, [*args, "--out", str(tmp_path)])
    assert result.exit_code != 0
    assert "unknown 3D packing 'rain'; choose from column, box, jammed_box" in result.output
    assert "Traceback" not in result.output


def test_scaling_resume_keeps_the_rows_it_has(tmp_path):
    kw = dict(solvers="apgd", n2d=[], steps=1, time_limit=60.0, out=tmp_path,
              progress=lambda line: None, packings=["jammed_box"])  # fmt: skip
    first = scaling.STUDY(n3d=[8], **kw)
    again = scaling.STUDY(n3d=[8, 27], resume=True, **kw)
    assert list(again.N) == [8, 27] and (again.steps_ok == "1/1").all()
    kept = again[again.N == 8].iloc[0]
    assert kept.wall_s == first.wall_s.iloc[0]
    assert len(pd.read_csv(tmp_path / "scaling.csv")) == 2
