"""``cocd bench seed-contacts`` and ``cocd bench margin`` on small columns, through the
command line."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
from typer.testing import CliRunner

from cocd.cli import app
from cocd.studies import margin, seed_contacts
from cocd.studies.table1 import SEED_ROWS

runner = CliRunner()


def written(out, name):
    for suffix in (".csv", ".md", ".meta.json"):
        assert (out / f"{name}{suffix}").is_file(), f"{name}{suffix} not written"
    meta = json.loads((out / f"{name}.meta.json").read_text())
    assert meta["name"] == name
    assert sorted(meta["files"]) == [f"{name}.csv", f"{name}.md"]
    assert f"# {meta['title']}" in (out / f"{name}.md").read_text()
    assert (out / "README.md").is_file()
    return meta


def test_seed_contacts_grow_with_the_threshold_and_meet_the_seed_count(tmp_path):
    args = ["bench", "seed-contacts", "--n2d", "20", "--n3d", "20", "--out", str(tmp_path)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    table = pd.read_csv(tmp_path / "seed_contacts.csv")
    assert list(table.columns) == ["case", "D_over_r", "Nc", "Nc_per_grain", "seed_Nc_per_grain"]
    seed = {(r["dim"], r["N"]): r["Nc"] / r["N"] for r in SEED_ROWS}
    cases = list(table.case.unique())
    assert [c[:2] for c in cases] == ["2D", "3D"]
    for case, target in zip(cases, (seed[(2, 8308)], seed[(3, 122932)]), strict=True):
        rows = table[table.case == case]
        fixed, found = rows[rows.seed_Nc_per_grain.isna()], rows[rows.seed_Nc_per_grain.notna()]
        assert list(fixed.D_over_r) == seed_contacts.FACTORS
        per = fixed.Nc_per_grain.to_numpy()
        # A wider threshold keeps every pair a narrower one found, and adds more.
        assert np.all(np.diff(per) >= 0) and per[-1] > per[0]
        assert (fixed.Nc > 0).all()
        (d,) = found.D_over_r
        assert found.seed_Nc_per_grain.iloc[0] == target
        assert 0.25 <= d <= 2.5
        # The interpolated threshold's count lies between those of its neighbours.
        lo = fixed[fixed.D_over_r <= d].Nc_per_grain.max()
        hi = fixed[fixed.D_over_r >= d].Nc_per_grain.min()
        assert lo <= found.Nc_per_grain.iloc[0] <= hi
    meta = written(tmp_path, "seed_contacts")
    assert meta["summary"].count("per grain (seed") == 2
    assert "D_over_r" in (tmp_path / "seed_contacts.md").read_text()


def test_margin_rows_for_each_threshold_on_both_collapses(tmp_path):
    args = ["--n3d", "40", "--steps3d", "6", "--n2d", "40", "--steps2d", "10"]
    result = runner.invoke(app, ["bench", "margin", *args, "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    table = pd.read_csv(tmp_path / "margin.csv")
    assert list(table.columns) == margin.COLUMNS
    assert len(table) == 12
    for dim, steps in (("3D", 6), ("2D", 10)):
        t = table[table.scene.str.startswith(dim)].set_index("threshold")
        assert len(t) == 6 and (t.steps == steps).all()
        cpg = t.contacts_per_grain
        # A wider fixed threshold gives more potential contacts per grain.
        assert cpg["d_max 0.5 r (fixed)"] <= cpg["d_max 1 r (fixed)"] < cpg["d_max 2 r (fixed)"]
        assert cpg["d_max 2 r (fixed)"] > 1.5 * cpg["d_max 0.5 r (fixed)"]
        # The margins that follow the motion cost far less than a fixed 2 r ...
        for name in ("0.5 r + skin 1", "0.5 r + skin 2", margin.DEFAULT):
            assert cpg[name] < cpg["d_max 2 r (fixed)"]
        # ... and let no pair through: the overlaps left are the solver's tolerance.
        wide = t.drop(index="d_max 0.5 r (fixed)")
        assert (wide.missed_pairs == 0).all() and (wide.steps_with_missed == 0).all()
        assert (t.penetration_max_r >= 0).all() and (t.penetration_max_r < 1e-3).all()
        assert (t.policy == ["record"] * 5 + ["redo"]).all()
        # No redo was needed, so the default stepped as the recording skin-2 row did.
        default, skin2 = t.loc[margin.DEFAULT], t.loc["0.5 r + skin 2"]
        assert default.redos == 0
        assert default.contacts_per_grain == skin2.contacts_per_grain
        assert default.penetration_max_r == skin2.penetration_max_r
    meta = written(tmp_path, "margin")
    assert meta["summary"].count("a fixed d_max of 0.5 r") == 2


def test_bad_options_are_one_line_errors(tmp_path):
    for args, message in (
        (["seed-contacts", "--n2d", "1"], "error: --n2d must be an integer >= 2, got 1"),
        (["margin", "--steps3d", "0"], "error: --steps3d must be an integer >= 1, got 0"),
        (["margin", "--n3d", "-5"], "error: --n3d must be an integer >= 2, got -5"),
    ):
        result = runner.invoke(app, ["bench", *args, "--out", str(tmp_path / "cli")])
        assert result.exit_code == 2, (args, result.output)
        assert result.output.strip() == message, (args, result.output)
    # The installed command, in a process of its own: one line on stderr, nothing written.
    proc = subprocess.run(
        [sys.executable, "-m", "cocd", "bench", "margin", "--n2d", "0", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip() == "error: --n2d must be an integer >= 2, got 0"
    assert "Traceback" not in proc.stdout + proc.stderr
    assert not (tmp_path / "margin.csv").exists()
