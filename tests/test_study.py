"""Studies: declared once, their commands generated; cocd/bench/README.md's example, run."""

from __future__ import annotations

import re
import sys
import types
from pathlib import Path

import pandas as pd
import pytest
import typer
from typer.testing import CliRunner

from cocd.bench import study
from cocd.cli import app

README = Path(__file__).resolve().parents[1] / "cocd" / "bench" / "README.md"
runner = CliRunner()


@pytest.fixture()
def example():
    """The worked example of cocd/bench/README.md, imported as a module and registered."""
    code = re.search(r"```python\n(.*?)```", README.read_text(), flags=re.S).group(1)
    module = types.ModuleType("cocd.studies.first_step")
    sys.modules[module.__name__] = module
    try:
        exec(compile(code, str(README), "exec"), module.__dict__)
        yield module
    finally:
        study._STUDIES.pop(("bench", "first-step"), None)
        del sys.modules[module.__name__]


def _app(s: study.Study) -> typer.Typer:
    one = typer.Typer(add_completion=False)
    one.command(s.name)(study.command(s))
    one.command("help")(lambda: None)  # two commands: Typer keeps the name on the line
    return one


def test_the_readme_example_runs_from_the_command_line_and_from_python(example, tmp_path):
    assert example.STUDY in study.studies("bench")
    args = ["first-step", "--n", "40,80", "--solvers", "clarabel", "--out", str(tmp_path)]
    result = runner.invoke(_app(example.STUDY), args)
    assert result.exit_code == 0, result.output
    table = pd.read_csv(tmp_path / "first_step.csv")
    assert list(table.problem) == ["column_2d_40", "column_2d_80"]
    assert (table.status == "optimal").all() and (table.solver == "clarabel").all()
    assert "first_step" in (tmp_path / "README.md").read_text()
    # From Python, the declared defaults fill what is not given.
    again = example.STUDY(n=(40,), out=tmp_path / "py")
    assert list(again.solver) == ["clarabel", "ipm"] and (again.tol == 1e-8).all()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--n", "0"], "--n must be positive integers, got '0'"),
        (["--n", "4,x"], "--n must be comma-separated integers"),
        (["--solvers", "nope"], "unknown solver 'nope'"),
        (["--tol", "0"], "--tol must be a finite number > 0, got 0.0"),
    ],
)
def test_bad_options_are_one_line_errors(example, tmp_path, args, message):
    result = runner.invoke(_app(example.STUDY), ["first-step", *args, "--out", str(tmp_path)])
    assert result.exit_code == 2, result.output
    assert message in result.output and "Traceback" not in result.output


def test_every_study_has_its_command_with_its_declared_options():
    import dataclasses

    for s in study.studies():
        result = runner.invoke(app, [s.group, s.name, "--help"])
        assert result.exit_code == 0, (s.name, result.output)
        text = " ".join(result.output.split())
        for f in dataclasses.fields(s.settings):
            flag = f.metadata.get("flag") or "--" + f.name.replace("_", "-")
            if not f.metadata.get("argument"):
                assert flag.split("/")[0] in text, (s.name, flag)


def test_old_names_are_hidden_aliases():
    bench = runner.invoke(app, ["bench", "--help"]).output
    validate = runner.invoke(app, ["validate", "--help"]).output
    assert "runout" in validate and "scaling" not in validate and "stability" not in validate
    assert "stability" in bench
    # The old names still run the same study, marked deprecated.
    assert "deprecated" in runner.invoke(app, ["validate", "scaling", "--help"]).output.lower()
    old_stability = " ".join(runner.invoke(app, ["validate", "stability", "--help"]).output.split())
    # The old validate command keeps the defaults it had (a 300-grain box, a run budget).
    assert "--n <int> Grains in the box. [default: 300]" in old_stability
    assert "[default: 60.0]" in old_stability


def test_a_second_study_of_the_same_name_is_refused():
    @dataclasses_frozen
    class Settings(study.StudySettings):
        pass

    table1 = next(s for s in study.studies("bench") if s.name == "table1")
    with pytest.raises(ValueError, match="already registered"):
        study.register(study.Study("table1", "bench", Settings, table1.run))


def test_settings_check_their_positive_fields_from_python_too(example):
    """The check the command line makes is the settings' own: Python callers meet it,
    and a study whose settings skip it is not registered."""
    from cocd.errors import CocdError
    from cocd.studies import hard, stability

    with pytest.raises(CocdError, match=r"^--tol must be a finite number > 0, got 0$"):
        example.Settings(tol=0)
    with pytest.raises(CocdError, match=r"^--time-limit must be a finite number > 0, got nan$"):
        hard.Settings(time_limit=float("nan"))
    with pytest.raises(CocdError, match=r"^--run-budget must be a finite number > 0"):
        stability.STUDY(run_budget=-1.0)  # dataclasses.replace makes the settings again
    assert stability.Settings(run_budget=None).run_budget is None  # None: no budget
    assert stability.Settings(time_limit=None).time_limit is None  # None: no limit
    for bad in ("1e-6", True, None):  # a string, a flag, and None where it means nothing
        with pytest.raises(CocdError, match=r"^--tol must be a finite number > 0"):
            hard.Settings(tol=bad)
    from cocd.validate import nscd

    with pytest.raises(CocdError, match=r"^--nscd-max-iter must be a whole number, got 0.5$"):
        nscd.Settings(nscd_max_iter=0.5)

    @dataclasses_frozen
    class Plain:
        tol: float = study.option(1e-8, "A tolerance.", positive=True)

    with pytest.raises(TypeError, match="StudySettings"):
        study.register(study.Study("plain", "bench", Plain, lambda cfg, *, out: None))
    # A list checks its items by its kind; "positive" on it would refuse every list.
    with pytest.raises(TypeError, match="positive is for a number"):
        study.option((1.0,), "Sizes.", kind="floats", positive=True)


def dataclasses_frozen(cls):
    import dataclasses

    return dataclasses.dataclass(frozen=True)(cls)


def test_an_out_that_cannot_be_written_is_refused_before_any_work(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("mine")
    result = runner.invoke(app, ["bench", "hard", "--out", str(blocker / "sub")])
    assert result.exit_code == 2 and "--out" in result.output
    assert "Traceback" not in result.output and blocker.read_text() == "mine"


def test_a_study_module_of_another_package_that_fails_is_said_not_fatal(monkeypatch):
    import importlib.metadata
    from types import SimpleNamespace

    def load():
        raise TypeError("study plain: settings must be a dataclass of StudySettings")

    broken = SimpleNamespace(name="plain", value="theirs.plain", load=load)
    monkeypatch.setattr(importlib.metadata, "entry_points", lambda group: [broken])
    with pytest.warns(UserWarning, match=r"the study module theirs.plain \(plain\) is not loaded"):
        names = {s.name for s in study.studies("bench")}
    assert "table1" in names
