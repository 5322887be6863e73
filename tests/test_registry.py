"""The solver registry: names, capabilities, availability, plug-ins."""

from __future__ import annotations

from importlib.metadata import EntryPoint

import numpy as np
import pytest

import solvers
from cocd import ProblemError, SolverError, SolverNotFound, Stepper, stack
from solvers import Solution, SolverInfo, Status, registry


@pytest.fixture
def clean_registry(monkeypatch):
    """A registry that forgets what a test adds to it."""
    monkeypatch.setattr(registry, "_registry", dict(registry.registered()))


def test_clarabel_is_available_with_its_capabilities():
    assert "clarabel" in solvers.available()
    info = solvers.get("clarabel")
    assert info.dims == (2, 3)
    assert info.formulation == "primal"
    assert info.convex and not info.warm_start and not info.needs_licence


def test_missing_package_is_unavailable_with_reason(clean_registry):
    solvers.register(
        SolverInfo(name="ghost", entry="ghost_pkg:solve", requires=("ghost_pkg_not_installed",))
    )
    assert "ghost" not in solvers.available()
    assert "ghost_pkg_not_installed" in solvers.unavailable()["ghost"]
    with pytest.raises(SolverNotFound, match="registered but unavailable: Python package"):
        solvers.get("ghost")


def test_licence_probe_reason(clean_registry):
    solvers.register(
        SolverInfo(name="licensed", entry="x:y", needs_licence=True, probe=lambda: "no licence")
    )
    assert solvers.unavailable()["licensed"] == "no licence"


def _copy_solver(problem, request, **options):
    """A test backend: answers with the warm start it was given (or zero)."""
    warm_start = request.warm_start
    p = np.zeros((problem.nc, problem.contact_dim)) if warm_start is None else warm_start
    return Solution(
        u=problem.velocity(p),
        p=p,
        status=Status.OPTIMAL,
        iterations=1,
        setup_time=0.0,
        solve_time=0.0,
        solver="copy",
        extras={"saw_warm_start": warm_start is not None},
    )


def test_third_party_backend_and_warm_start(clean_registry):
    solvers.register(
        SolverInfo(
            name="copy",
            entry=f"{__name__}:_copy_solver",
            warm_start=True,
            dims=(2,),
        )
    )
    assert "copy" in solvers.available()
    with pytest.raises(ValueError, match="already registered"):
        solvers.register(SolverInfo(name="copy", entry="x:y"))
    # Dimension capability is enforced.
    with pytest.raises(ProblemError, match=r"handles dimensions \(2,\), not a 3D"):
        Stepper(stack(1, dim=3), 1e-3, solver="copy")


@pytest.mark.unchecked_solutions
def test_declared_options_are_checked_for_every_backend(clean_registry):
    problem = _stack_problem()
    solvers.register(
        SolverInfo(name="copy", entry=f"{__name__}:_copy_solver", accepts=("alpha", "beta"))
    )
    assert solvers.solve(problem, "copy", alpha=1).status is Status.OPTIMAL
    with pytest.raises(
        ProblemError, match="copy has no option 'gamma'; its options are alpha, beta"
    ):
        solvers.solve(problem, "copy:gamma=2")
    solvers.register(SolverInfo(name="bare", entry=f"{__name__}:_copy_solver", accepts=()))
    with pytest.raises(ProblemError, match="bare has no option 'alpha'; its options are none"):
        solvers.solve(problem, "bare", alpha=1)
    # Undeclared (None): the options reach the backend, which checks them itself.
    solvers.register(SolverInfo(name="open", entry=f"{__name__}:_copy_solver"))
    assert solvers.solve(problem, "open", anything=1).status is Status.OPTIMAL
    # Every built-in backend with its own option list names it.
    for name in ("ipm", "pgs", "bgs", "apgd", "nscd", "fp"):
        accepts = solvers.get(name).accepts
        assert accepts, name
        with pytest.raises(
            ProblemError, match=f"has no option 'rho'; its options are {accepts[0]}"
        ):
            solvers.solve(problem, name, rho=1.0)


def _keyword_solver(problem, *, tol, warm_start, max_iter, time_limit, verbose, **options):
    """A test backend of the earlier keyword form: says what it was given."""
    p = np.zeros((problem.nc, problem.contact_dim))
    given = (tol, warm_start, max_iter, time_limit, verbose, options)
    return Solution(problem.velocity(p), p, Status.MAX_ITER, 0, 0.0, 0.0, "kw", {"given": given})


def test_a_backend_of_the_keyword_form_gets_the_request_as_keywords(clean_registry):
    solvers.register(SolverInfo(name="kw", entry=f"{__name__}:_keyword_solver", accepts=("a",)))
    sol = solvers.solve(_stack_problem(), "kw", 1e-6, None, 7, 2.0, True, a=1)
    assert sol.extras["given"] == (1e-6, None, 7, 2.0, True, {"a": 1})


def _stack_problem():
    from cocd import assemble, detect_contacts

    scene = stack(2, dim=2, mu=0.3)
    return assemble(scene, detect_contacts(scene), 1e-3)


@pytest.mark.unchecked_solutions
def test_stepper_warm_starts_matched_by_pair(clean_registry):
    solvers.register(SolverInfo(name="copy", entry=f"{__name__}:_copy_solver", warm_start=True))
    # "copy" answers with the warm start (zero first): no residual or energy check.
    stepper = Stepper(
        stack(3, dim=2), 1e-3, solver="copy", residual_factor=None, energy_factor=None
    )
    stepper.step()
    assert stepper.solution.extras["saw_warm_start"] is False
    stepper.step()
    assert stepper.solution.extras["saw_warm_start"] is True


def test_warm_start_ignored_with_warning_by_clarabel():
    stepper = Stepper(stack(2, dim=2), 1e-3)
    stepper.step()
    problem, p = stepper.problem, stepper.solution.p
    with pytest.warns(UserWarning, match="does not use a warm start"):
        solvers.solve(problem, "clarabel", warm_start=p)


def test_entry_point_plugins_are_loaded(monkeypatch):
    ep = EntryPoint(name="copy_ep", value=f"{__name__}:PLUGIN", group=registry.ENTRY_POINT_GROUP)
    monkeypatch.setattr(registry, "entry_points", lambda group: [ep])
    monkeypatch.setattr(registry, "_registry", {})
    monkeypatch.setattr(registry, "_entry_points_loaded", False)
    assert "copy_ep" in solvers.available()
    assert "clarabel" in solvers.available()


def test_broken_plugin_warns_instead_of_breaking(monkeypatch):
    ep = EntryPoint(name="broken", value="no_such_module_xyz:thing", group="cocd.solvers")
    monkeypatch.setattr(registry, "entry_points", lambda group: [ep])
    monkeypatch.setattr(registry, "_registry", {})
    monkeypatch.setattr(registry, "_entry_points_loaded", False)
    with pytest.warns(RuntimeWarning, match="'broken' could not be loaded"):
        names = solvers.available()
    assert "clarabel" in names


def _crashing_solver(problem, request, **options):
    raise ZeroDivisionError("boom")


@pytest.mark.unchecked_solutions
def test_backend_crash_becomes_solver_error(clean_registry):
    solvers.register(SolverInfo(name="crash", entry=f"{__name__}:_crashing_solver"))
    with pytest.raises(SolverError, match=r"solver 'crash' failed .*ZeroDivisionError: boom"):
        Stepper(stack(2, dim=2), 1e-3, solver="crash").step()


@pytest.mark.unchecked_solutions
def test_unsolved_step_names_step_and_backend():
    stepper = Stepper(stack(5, dim=3, mu=0.5), 1e-3, max_iter=1)
    with pytest.raises(SolverError, match=r"step 1 .*clarabel: returned status max_iter"):
        stepper.step()


PLUGIN = SolverInfo(name="copy_ep", entry=f"{__name__}:_copy_solver", warm_start=True)


def test_suite_wide_check_catches_a_wrong_answer(clean_registry):
    """The conftest check on every solve fails a backend that claims a wrong answer."""
    solvers.register(SolverInfo(name="copy", entry=f"{__name__}:_copy_solver"))
    stepper = Stepper(stack(2, dim=2), 1e-3, solver="copy")  # answers p = 0: grains fall through
    with pytest.raises(AssertionError, match=r"copy: ccp_residual 1 > 10 tol"):
        stepper.step()


@pytest.mark.parametrize("name", ["clarabel", "pgs", "apgd"])
def test_an_option_in_the_name_wins_over_the_same_argument(name):
    # The README's form `--solver clarabel:max_iter=3` beside the run's own max_iter.
    stepper = Stepper(stack(6, dim=2), 1e-3)
    stepper.run(2)
    problem = stepper.problem
    sol = solvers.solve(problem, f"{name}:max_iter=1:tol=1e-14", tol=1e-3, max_iter=500)
    assert sol.iterations == 1 and sol.status == "max_iter"
    with pytest.raises(ProblemError, match="a warm start cannot be given in a solver name"):
        solvers.solve(problem, f"{name}:warm_start=1")


def test_true_and_false_in_a_name_are_read_as_toml_and_the_shell_write_them():
    base, options = registry._split("nscd:symmetric=false:newton=True", registry.registered())
    assert base == "nscd" and options == {"symmetric": False, "newton": True}
    problem = _stack_problem()
    # The lower-case word is the same option as Python's: the same sweeps, not a flipped one.
    lower = solvers.solve(problem, "nscd:symmetric=false", tol=1e-10)
    upper = solvers.solve(problem, "nscd:symmetric=False", tol=1e-10)
    assert lower.iterations == upper.iterations


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("ipm:polish=maybe", "ipm: polish must be True or False, got 'maybe'"),
        ("nscd:symmetric=1", "nscd: symmetric must be True or False, got 1"),
        ("pgs:verbose=yes", "pgs: verbose must be True or False, got 'yes'"),
        ("ipm:correctors=-1", "ipm: setting correctors must be an integer >= 0, got -1"),
        ("ipm:correctors=1.5", "ipm: setting correctors must be an integer, got 1.5"),
        ("clarabel:max_step_fraction=abc", "clarabel: setting max_step_fraction must be a number"),
        ("clarabel:max_threads=1.5", "clarabel: setting max_threads must be an integer"),
        ("clarabel:presolve_enable=2", "clarabel: setting presolve_enable must be True or False"),
        ("scs:alpha=abc", "scs: setting alpha must be a number, got 'abc'"),
        ("scs:normalize=0", "scs: setting normalize must be True or False, got 0"),
    ],
)
def test_an_option_of_the_wrong_type_is_a_one_line_error(name, message):
    with pytest.raises(ProblemError, match=f"^{message}"):
        solvers.solve(_stack_problem(), name)


@pytest.mark.parametrize(
    "key", ["problem", "solver", "tol", "max_iter", "time_limit", "warm_start"]
)
def test_solver_options_cannot_set_what_the_stepper_gives_the_backend(key):
    with pytest.raises(ProblemError, match=f"solver_options cannot set '{key}', which the stepper"):
        Stepper(stack(2, dim=2), 1e-3, solver_options={key: 1})


@pytest.mark.parametrize(
    ("solver", "options", "message"),
    [
        ("ipm", {"polish": "maybe"}, "ipm: polish must be True or False"),
        ("ipm:polish=maybe", {}, "ipm: polish must be True or False"),
        ("pgs", {"rho": 1.0}, "pgs has no option 'rho'"),
    ],
)
def test_a_stepper_refuses_bad_options_before_any_step(solver, options, message):
    with pytest.raises(ProblemError, match=message):
        Stepper(stack(2, dim=2), 1e-3, solver=solver, solver_options=options)
