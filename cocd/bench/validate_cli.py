"""``cocd validate``: the seeds' physics cases (:mod:`cocd.bench.validate`,
:mod:`cocd.bench.runout`, :mod:`cocd.bench.avalanche`).

Each command runs its simulations (resumable run files under
``OUT/runs/<case>/``), writes its table and figures under ``--out`` (default
``cocd-results/validation``; the committed figures: ``--out results/validation``)
and rebuilds ``OUT/README.md``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer

from cocd.bench.cli import _floats
from cocd.errors import CocdError
from cocd.exits import fail

validate_app = typer.Typer(
    rich_markup_mode=None,
    add_completion=False,
    no_args_is_help=True,
    help="Reproduce the seeds' physics: time step, NSCD, erodible beds, stability, "
    "runout scaling, avalanche angles.",
)

Out = Annotated[Path, typer.Option("--out", help="Output directory.")]
N = Annotated[int, typer.Option("--n", help="Discs in the column.")]
Solver = Annotated[str, typer.Option("--solver", help="Convex backend of the COCD runs.")]
Tol = Annotated[float, typer.Option("--tol", help="Tolerance of the convex backend.")]
Fallback = Annotated[
    str, typer.Option("--fallback", help="Backends tried when a step fails (comma-separated).")
]
Fresh = Annotated[
    bool, typer.Option("--fresh", help="Start the runs over instead of resuming them.")
]
Mu = Annotated[float, typer.Option("--mu", help="Friction coefficient (grains and walls).")]
DEFAULT_OUT = Path("cocd-results/validation")


def _names(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def _numbers(text: str, what: str) -> list[float]:
    """Comma-separated numbers >= 0 (a slope or a layer thickness may be 0)."""
    try:
        values = [float(v) for v in _names(text)]
    except ValueError:
        raise CocdError(f"{what} must be comma-separated numbers, got {text!r}") from None
    if not values:
        raise CocdError(f"{what} is empty")
    return values


def _go(job: Callable[[], object]) -> None:
    try:
        job()
    except CocdError as exc:
        fail(exc)


@validate_app.command()
def timestep(
    n: N = 400,
    dts: Annotated[str, typer.Option("--dts", help="Time steps (s).")] = "1e-3,1e-4,5e-5",
    times: Annotated[str, typer.Option("--times", help="Profile times (s).")] = "0.02,0.06,0.3",
    mu: Mu = 0.3,
    solver: Solver = "ipm",
    tol: Tol = 1e-8,
    fallback: Fallback = "clarabel",
    fresh: Fresh = False,
    out: Out = DEFAULT_OUT,
) -> None:
    """Fig. 2: profiles of a 2D collapse at several time steps, error against the smallest."""
    from cocd.bench import validate

    _go(
        lambda: validate.timestep(
            n=n,
            dts=_floats(dts, "--dts"),
            times=_floats(times, "--times"),
            mu=mu,
            solver=solver,
            tol=tol,
            fallback=_names(fallback),
            out=out,
            fresh=fresh,
        )
    )


@validate_app.command()
def nscd(
    n: N = 400,
    dt: Annotated[float, typer.Option("--dt", help="Time step (s).")] = 1e-3,
    times: Annotated[
        str, typer.Option("--times", help="Profile times in units of sqrt(H0/g).")
    ] = "1,2,4,8",
    mu: Mu = 0.3,
    solver: Solver = "ipm",
    tol: Tol = 1e-8,
    nscd_tol: Annotated[float, typer.Option("--nscd-tol", help="Tolerance of nscd.")] = 1e-5,
    nscd_max_iter: Annotated[
        int, typer.Option("--nscd-max-iter", help="Sweeps allowed to nscd per step.")
    ] = 100000,
    nscd_symmetric: Annotated[
        bool,
        typer.Option(
            "--nscd-symmetric/--nscd-forward", help="Alternate nscd's sweep direction or not."
        ),
    ] = True,
    fallback: Fallback = "clarabel",
    fresh: Fresh = False,
    out: Out = DEFAULT_OUT,
) -> None:
    """Fig. 4: the same 2D collapse with a convex backend (COCD) and with nscd."""
    from cocd.bench import validate

    _go(
        lambda: validate.nscd(
            n=n,
            dt=dt,
            times_T=_floats(times, "--times"),
            mu=mu,
            convex=solver,
            tol=tol,
            nscd_tol=nscd_tol,
            nscd_max_iter=nscd_max_iter,
            nscd_symmetric=nscd_symmetric,
            fallback=_names(fallback),
            out=out,
            fresh=fresh,
        )
    )


@validate_app.command()
def erodible(
    n: N = 400,
    slopes: Annotated[str, typer.Option("--slopes", help="Bed slopes (degrees).")] = "22",
    layers: Annotated[
        str, typer.Option("--layers", help="Layer thicknesses in mean diameters (0: none).")
    ] = "0,3,5",
    until: Annotated[float, typer.Option("--until", help="Simulated time (s).")] = 2.0,
    dt: Annotated[float, typer.Option("--dt", help="Time step (s).")] = 1e-3,
    mu: Mu = 0.9,
    bed_length: Annotated[float, typer.Option("--bed-length", help="Bed length (m).")] = 1.5,
    solver: Solver = "ipm",
    tol: Tol = 1e-6,
    fallback: Fallback = "clarabel",
    fresh: Fresh = False,
    out: Out = DEFAULT_OUT,
) -> None:
    """Fig. 9: 2D collapses on a slope over erodible layers; front against time."""
    from cocd.bench import validate

    _go(
        lambda: validate.erodible(
            n=n,
            slopes=_numbers(slopes, "--slopes"),
            layers_d=_numbers(layers, "--layers"),
            until=until,
            dt=dt,
            mu=mu,
            bed_length=bed_length,
            solver=solver,
            tol=tol,
            fallback=_names(fallback),
            out=out,
            fresh=fresh,
        )
    )


@validate_app.command()
def stability(
    solvers: Annotated[
        str, typer.Option("--solvers", help="Backends (comma-separated).")
    ] = "ipm,clarabel,scs,apgd,pgs,nscd",
    eps_list: Annotated[
        str, typer.Option("--eps-list", help="Tolerances.")
    ] = "1e-1,1e-2,1e-3,1e-4,1e-6",
    n: Annotated[int, typer.Option("--n", help="Grains in the box.")] = 300,
    dim: Annotated[int, typer.Option("--dim", help="2 or 3.")] = 3,
    t_end: Annotated[float, typer.Option("--t-end", help="Duration in sqrt(H/g).")] = 5.0,
    dt: Annotated[float, typer.Option("--dt", help="Time step (s).")] = 1e-2,
    time_limit: Annotated[float, typer.Option("--time-limit", help="Seconds per solve.")] = 30.0,
    run_budget: Annotated[
        float, typer.Option("--run-budget", help="Seconds per (solver, eps) run.")
    ] = 60.0,
    out: Out = DEFAULT_OUT,
) -> None:
    """Fig. 3: the largest tolerance at which each backend keeps a static box at rest."""
    from cocd.bench import validate

    _go(
        lambda: validate.stability(
            solvers=solvers,
            eps_list=_floats(eps_list, "--eps-list"),
            n=n,
            dim=dim,
            t_end=t_end,
            dt=dt,
            time_limit=time_limit,
            run_budget=run_budget,
            out=out,
        )
    )


@validate_app.command()
def scaling(
    aspects: Annotated[
        str, typer.Option("--aspects", help="Aspect ratios H0/L0.")
    ] = "0.5,0.9,1.6,3,5.5,10",
    area: Annotated[float, typer.Option("--area", help="Column cross-section L0 H0 (m^2).")] = 0.02,
    diameter: Annotated[float, typer.Option("--diameter", help="Mean grain diameter (m).")] = 0.007,
    mu: Mu = 0.5,
    rest_t: Annotated[
        float, typer.Option("--rest-T", help="Run time in units of sqrt(H0/g).")
    ] = 12.0,
    solver: Solver = "ipm",
    tol: Tol = 1e-6,
    fallback: Fallback = "clarabel",
    fresh: Fresh = False,
    out: Out = DEFAULT_OUT,
) -> None:
    """Seed 001: runout and deposit height of 2D collapses against the aspect ratio."""
    from cocd.bench import runout

    _go(
        lambda: runout.scaling(
            aspects=_floats(aspects, "--aspects"),
            area=area,
            diameter=diameter,
            mu=mu,
            rest_T=rest_t,
            solver=solver,
            tol=tol,
            fallback=_names(fallback),
            out=out,
            fresh=fresh,
        )
    )


@validate_app.command()
def avalanche(
    mus: Annotated[str, typer.Option("--mus", help="Friction coefficients.")] = "0.2,0.4,0.8",
    n: Annotated[int, typer.Option("--n", help="Discs in the layer.")] = 300,
    width_d: Annotated[float, typer.Option("--width-d", help="Box width in diameters.")] = 50.0,
    step_deg: Annotated[float, typer.Option("--step-deg", help="Tilt step (degrees).")] = 0.5,
    hold: Annotated[float, typer.Option("--hold", help="Seconds held at each tilt.")] = 0.15,
    solver: Solver = "ipm",
    tol: Tol = 1e-6,
    fallback: Fallback = "clarabel",
    fresh: Fresh = False,
    out: Out = DEFAULT_OUT,
) -> None:
    """Seed 001: avalanche and stop angles of a tilted layer against grain friction."""
    from cocd.bench import avalanche as mod

    _go(
        lambda: mod.avalanche(
            mus=_floats(mus, "--mus"),
            n=n,
            width_d=width_d,
            step_deg=step_deg,
            hold=hold,
            solver=solver,
            tol=tol,
            fallback=_names(fallback),
            out=out,
            fresh=fresh,
        )
    )
