"""Run-time estimates of the harness commands (cocd.bench.estimate)."""

import json

import pytest

from cocd.bench import estimate


def test_work_grows_as_the_power_of_n_plus_a_cost_per_solve():
    one = estimate.work([(1000, 1)])
    assert one == pytest.approx(1.0 + estimate.PER_SOLVE)
    big = estimate.work([(8000, 3)])
    assert big == pytest.approx(3 * (8.0**estimate.EXPONENT + estimate.PER_SOLVE))
    assert estimate.work([(1000, 2), (8000, 3)]) == pytest.approx(2 * one + big)
    assert estimate.work([]) == 0.0


@pytest.mark.parametrize(
    "seconds, text",
    [(0.2, "1 s"), (40.4, "40 s"), (600, "10 min"), (5400, "1.5 h"), (float("nan"), "unknown")],
)
def test_format_seconds(seconds, text):
    assert estimate.format_seconds(seconds) == text


def test_shipped_rate_then_the_recorded_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no ./results records
    lines: list[str] = []
    solves = [(2000, 10)]
    first = estimate.announce("hard", solves, out=tmp_path, progress=lines.append)
    assert first == pytest.approx(estimate.RATES["hard"] * estimate.work(solves))
    assert lines[-1].startswith("hard: 10 solves, the largest of 2000 grains; expected ")
    assert "from timings on a 2-core machine" in lines[-1]
    # A finished run records its time and work; the next estimate scales from it.
    record = estimate.record()
    assert set(record) == {"elapsed_s", "work_units", "workers"} and record["workers"] == 1
    assert record["work_units"] == pytest.approx(estimate.work(solves), rel=1e-6)
    meta = tmp_path / "hard.meta.json"
    meta.write_text(json.dumps({"elapsed_s": 120.0, "work_units": record["work_units"]}))
    again = estimate.announce("hard", [(2000, 20)], out=tmp_path, progress=lines.append)
    assert again == pytest.approx(240.0, rel=1e-6)
    assert f"scaled from the run recorded in {meta}" in lines[-1] and "4 min" in lines[-1]
    # Made by 2 workers: 120 s of wall time are 240 s of one worker's; asked of 4
    # workers, the same work takes a quarter of that.
    meta.write_text(
        json.dumps({"elapsed_s": 120.0, "work_units": record["work_units"], "workers": 2})
    )
    assert estimate.announce("hard", solves, out=tmp_path, workers=4, progress=lines.append) == (
        pytest.approx(60.0, rel=1e-6)
    )
    assert estimate.record()["workers"] == 4
    # Three quarters of it kept (read back): a quarter is left to make.
    estimate.kept(0.25, "3 of 4 runs kept", progress=lines.append)
    assert lines[-1] == "hard: 3 of 4 runs kept; the rest should take 15 s"
    # The kept runs' own timing: 3 units made in 90 s of one worker are 30 s a unit,
    # so the quarter left (of the announced work), shared by 4 workers, takes
    # 30 * work / 4 / 4 s.
    estimate.kept(0.25, "3 of 4 runs kept", progress=lines.append, measured=(90.0, 3.0))
    rest = 30.0 * estimate.work(solves) / 16
    assert lines[-1] == (
        f"hard: 3 of 4 runs kept; the rest should take {estimate.format_seconds(rest)} "
        "(at the kept runs' rate)"
    )
    # One run left: of the 4 workers, one is busy.
    estimate.kept(0.25, "3 of 4 runs kept", progress=lines.append, measured=(90.0, 3.0), runs=1)
    assert lines[-1].endswith(f"take {estimate.format_seconds(4 * rest)} (at the kept runs' rate)")
    estimate.kept(0.25, "3 of 4 runs kept", progress=lines.append, runs=1)
    assert lines[-1] == "hard: 3 of 4 runs kept; the rest should take 60 s"
    # Kept runs without a timing (made before it was kept): the announced rate.
    estimate.kept(0.25, "3 of 4 runs kept", progress=lines.append, measured=(0.0, 3.0))
    assert lines[-1] == "hard: 3 of 4 runs kept; the rest should take 15 s"


def test_unreadable_record_falls_back_to_the_shipped_rate(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "table1.meta.json").write_text("{not json")
    lines: list[str] = []
    seconds = estimate.announce("table1", [(500, 4)], out=tmp_path, progress=lines.append)
    assert seconds == pytest.approx(estimate.RATES["table1"] * estimate.work([(500, 4)]))
    assert "from timings on a 2-core machine" in lines[-1]


def test_a_record_of_nothing_solved_keeps_the_same_commands_earlier_timing(tmp_path, monkeypatch):
    """Redrawn from kept runs (nothing solved), a record keeps the time and work of the
    same command's earlier record, and when they were taken; another command's
    record does not inherit them."""
    from cocd.bench import report

    def record(command: str, solved: float) -> dict:
        monkeypatch.setattr(estimate, "_current", {})
        estimate.announce("t", [(1000, 10)], out=tmp_path, progress=lambda _: None)
        estimate.made(1000, solved)
        report.write_meta(tmp_path, "t", title="T", files=[], command=command)
        return json.loads((tmp_path / "t.meta.json").read_text())

    first = record("cocd x", 10)
    assert first["work_units"] > 0 and "timed" not in first
    for _ in range(2):  # read back twice: the first record's timing and time stay
        again = record("cocd x", 0)
        assert again["work_units"] == first["work_units"]
        assert again["elapsed_s"] == first["elapsed_s"] and again["timed"] == first["written"]
    assert "timed_on" not in again  # the same machine
    other = record("cocd x --more", 0)
    assert other["work_units"] == 0 and "timed" not in other


def test_a_rebuild_on_another_machine_keeps_the_timing_and_names_its_machine(tmp_path, monkeypatch):
    """Read back on another processor, the same command's record keeps the earlier
    time and work, and says which processor and cores they were taken on; a later
    rebuild on a third machine still names the first."""
    from cocd.bench import report

    def record(cpu: str, solved: float) -> dict:
        monkeypatch.setattr(estimate, "_current", {})
        monkeypatch.setattr(report, "machine_info", lambda: {"cpu": cpu, "cores": 2})
        estimate.announce("t", [(1000, 10)], out=tmp_path, progress=lambda _: None)
        estimate.made(1000, solved)
        report.write_meta(tmp_path, "t", title="T", files=[], command="cocd x")
        return json.loads((tmp_path / "t.meta.json").read_text())

    first = record("Intel", 10)
    moved = record("AMD", 0)
    assert moved["machine"]["cpu"] == "AMD" and moved["work_units"] == first["work_units"]
    assert moved["elapsed_s"] == first["elapsed_s"]
    assert moved["timed_on"] == {"cpu": "Intel", "cores": 2}
    assert record("Other", 0)["timed_on"] == {"cpu": "Intel", "cores": 2}
    back = record("Intel", 0)  # on the first machine again: nothing to name
    assert back["elapsed_s"] == first["elapsed_s"] and "timed_on" not in back
    assert record("AMD", 5)["work_units"] != first["work_units"]  # a new solve replaces it
