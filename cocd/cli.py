"""The ``cocd`` command.

``cocd run`` (also ``python -m cocd``) runs a small 2D column collapse and
prints per-step statistics; ``cocd solvers`` lists the backends; ``cocd problem``
reads and solves external problem files (FCLib HDF5, Siconos text);
``cocd bench`` runs the benchmark harness (:mod:`cocd.bench`); ``cocd validate``
reproduces the seed papers' physics cases (:mod:`cocd.validate`).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

import solvers
from cocd.bench.cli import bench_app, validate_app
from cocd.errors import CocdError
from cocd.exits import EXIT_INTERRUPTED, EXIT_NOT_SOLVED, OneLineErrors, fail
from cocd.outputs import check_run_folder, writable_file, writable_folder
from cocd.problem_cli import problem_app

app = typer.Typer(
    cls=OneLineErrors,
    rich_markup_mode=None,
    add_completion=False,
    no_args_is_help=False,
    help="Granular media with hard Coulomb contact, one convex conic problem per step. "
    "With no command, `cocd` runs the default scene into ./cocd-runs/default, as `cocd run` does.",
)
app.add_typer(bench_app, name="bench")
app.add_typer(validate_app, name="validate")
app.add_typer(problem_app, name="problem")
export_app = typer.Typer(
    rich_markup_mode=None,
    add_completion=False,
    no_args_is_help=True,
    help="Export a run file for other tools.",
)
app.add_typer(export_app, name="export")
console = Console(soft_wrap=True)


def _print_version(value: bool) -> None:
    if value:
        from cocd.provenance import provenance

        made = provenance()
        commit = f" (git {made['commit'][:12]}{', modified' if made['dirty'] else ''})"
        typer.echo(f"cocd {made['cocd']}" + (commit if made["commit"] else ""))
        raise typer.Exit()


@app.callback(invoke_without_command=True)
def main(
    ctx: typer.Context,
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_print_version, is_eager=True, help="Print the version."
        ),
    ] = False,
) -> None:
    """With no command, run the default scene (same as ``cocd run``)."""
    if ctx.invoked_subcommand is None:
        ctx.invoke(run)


def _run_keys() -> str:
    """The ``[run]`` keys of a scene file, for ``cocd run --help``."""
    from cocd.config import RunSection

    lines = []
    for name, field in RunSection.model_fields.items():
        default = (
            "none" if field.default is None else repr(field.get_default(call_default_factory=True))
        )
        lines.append(f"{name} ({default}): {field.description or ''}")
    return "\n\n".join(lines)


@app.command(
    help="Run a scene file and write OUT/run.h5 (frames, contacts, statistics) and "
    "OUT/stats.csv.\n\nOptions given here override the scene file's [run] table. Without "
    "a scene file: the collapse of a 2D column of 300 discs for 0.1 s.\n\nThe [run] keys "
    "of a scene file:\n\n" + _run_keys()
)
def run(
    scene: Annotated[
        Path | None,
        typer.Argument(help="Scene file (TOML, see examples/); default: a 2D collapse."),
    ] = None,
    solver: Annotated[
        str | None, typer.Option("--solver", help="Backend (see `cocd solvers`).")
    ] = None,
    tol: Annotated[float | None, typer.Option("--tol", help="Backend tolerance.")] = None,
    until: Annotated[
        float | None, typer.Option("--until", help="Simulated time at the end (s).")
    ] = None,
    steps: Annotated[
        int | None, typer.Option("--steps", help="Number of steps (instead of --until).")
    ] = None,
    dt: Annotated[float | None, typer.Option("--dt", help="Time step (s).")] = None,
    frame_every: Annotated[
        int | None, typer.Option("--frame-every", help="Steps between saved frames.")
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option("--out", help="Output folder (default cocd-runs/<scene name>)."),
    ] = None,
    resume: Annotated[
        bool, typer.Option("--resume", help="Continue the run in --out from its last frame.")
    ] = False,
    force: Annotated[
        bool,
        typer.Option("--force", help="Replace a run already in --out (and its stats and plots)."),
    ] = False,
    fallback: Annotated[
        str | None,
        typer.Option(
            "--fallback", help="Backends tried in turn when a step fails (comma-separated)."
        ),
    ] = None,
) -> None:
    """Run a scene file and write OUT/run.h5 (frames, contacts, statistics) and OUT/stats.csv.

    Options given here override the scene file's [run] table. Without a scene
    file: the collapse of a 2D column of 300 discs for 0.1 s.
    """
    from cocd.config import DEFAULT_CONFIG, build_scene, load_config, parse_config
    from cocd.runs import run as run_scene

    display: _ProgressDisplay | None = None
    folder: Path | None = None
    try:
        if scene is None:
            config, name, text = parse_config(DEFAULT_CONFIG, "default scene"), "default", ""
        else:
            config, name = load_config(scene), scene.stem
            text = scene.read_text(encoding="utf-8")
        overrides: dict[str, Any] = {
            k: v
            for k, v in dict(
                solver=solver, tol=tol, until=until, steps=steps, dt=dt, frame_every=frame_every
            ).items()
            if v is not None
        }
        if fallback is not None:
            overrides["fallback"] = [name for name in fallback.split(",") if name]
        if steps is not None and until is not None:
            raise CocdError("give --steps or --until, not both")
        if resume and force:
            raise CocdError("give --resume or --force, not both")
        if steps is not None:
            overrides["until"] = None
        elif until is not None:
            overrides["steps"] = None
        data = config.model_dump()
        data["run"].update(overrides)
        config = parse_config(data, "command line")
        import solvers as registry

        for backend in (config.run.solver, *config.run.fallback):
            registry.get(backend)  # an unknown backend fails before any work
        folder = out if out is not None else Path("cocd-runs") / name
        source = str(scene) if scene is not None else "default scene"
        check_run_folder(folder, resume=resume, force=force)
        fresh = not resume
        built = build_scene(config, source) if fresh else None  # bad parameters fail here
        rc = config.run
        console.print(
            f"{name}: {config.builder}({', '.join(f'{k}={v}' for k, v in config.params.items())})"
            f"; dt = {rc.dt:g} s, {config.n_steps()} steps, solver {rc.solver}, tol {rc.tol:g}"
            f" -> {folder / 'run.h5'}",
            highlight=False,
        )
        display = _ProgressDisplay()
        import numpy as np

        # Overflow and 0/0 in a step that blows up are not said as numpy warnings: the
        # step's own checks (energy, residuals, NaN) end the run with one line saying so.
        with display, np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            summary = run_scene(
                config, folder, resume=resume, scene_file=text, progress=display.update,
                source=source, scene=built, force=force,
            )  # fmt: skip
    except CocdError as exc:
        fail(exc)
        return
    except KeyboardInterrupt:
        given = dict(
            solver=solver, tol=tol, until=until, steps=steps, dt=dt, frame_every=frame_every,
            out=out, fallback=fallback,
        )  # fmt: skip
        _interrupted(folder, scene, given, display.reached if display is not None else None)
        raise typer.Exit(code=EXIT_INTERRUPTED) from None
    from cocd.io.runfile import RunFile, units

    with RunFile(summary.path) as rf:
        stats = rf.stats()
        unit = units(rf.dim)
    named = {
        k: f"{k}_{unit[k].replace(' ', '_').replace('/', '_per_')}" for k in stats if k in unit
    }
    stats.rename(columns=named).to_csv(summary.path.with_name("stats.csv"), index=False)
    if summary.resumed_from_step:
        console.print(f"resumed from step {summary.resumed_from_step}", highlight=False)
    if len(stats):
        console.print(
            f"{summary.steps} steps, {summary.frames} frames; mean Nc {stats.nc.mean():.0f}, "
            f"iterations {stats.iterations.mean():.1f}, solve {stats.solve_time.mean():.4f} s/step"
            f", max ccp_residual {stats.ccp_residual.max():.2e}; wrote {summary.path} and "
            f"{summary.path.with_name('stats.csv')}",
            highlight=False,
        )
        fell_back = stats[stats.solver != config.run.solver]
        if len(fell_back):
            by = ", ".join(f"{n} by {s}" for s, n in fell_back.solver.value_counts().items())
            console.print(
                f"{len(fell_back)} of {len(stats)} steps answered by a fallback backend ({by})",
                highlight=False,
            )


def _interrupted(
    folder: Path | None, scene: Path | None, given: dict[str, Any], reached: Any
) -> None:
    """Say, after Ctrl-C, where the run stopped, what it kept and how to go on."""
    import shlex

    from cocd.io.runfile import RunFile
    from cocd.runs import RUN_FILE

    if folder is None:
        typer.echo("interrupted before the run started; nothing was written.", err=True)
        return
    path = folder / RUN_FILE
    where = f"step {reached.step} (t = {reached.t:.4g} s)" if reached is not None else "the start"
    kept = "nothing was written"
    if path.exists():
        try:
            with RunFile(path) as rf:
                last = rf.frame(-1)
                kept = f"{path} keeps frames up to step {last.step} (t = {last.time:.4g} s)"
        except CocdError:
            kept = f"{path} cannot be read"
    parts = ["cocd", "run"] + ([str(scene)] if scene is not None else [])
    for key, value in given.items():
        if value is not None:
            parts += [
                f"--{key.replace('_', '-')}",
                f"{value:g}" if isinstance(value, float) else str(value),
            ]
    typer.echo(f"interrupted at {where}; {kept}.", err=True)
    if path.exists():
        typer.echo(f"continue with: {shlex.join([*parts, '--resume'])}", err=True)


class _ProgressDisplay:
    """A rich progress bar on a terminal; a plain line every few seconds otherwise.

    The time left is estimated from the steps after this call's first, whose
    time includes compiling the numba kernels. The step count and the time
    left come first, so a narrow terminal cuts the statistics, not them.
    """

    EVERY = 5.0  # seconds between plain lines

    def __init__(self, out: Console | None = None) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

        self.console = console if out is None else out
        self.live = self.console.is_terminal
        self.last_line = -float("inf")
        self.task: Any = None
        self.reached: Any = None  # the last step's record
        self.first_elapsed: float | None = None
        self.bar = Progress(
            TextColumn("step"),
            MofNCompleteColumn(),
            BarColumn(bar_width=16),
            TextColumn("{task.fields[left]}"),
            TextColumn("{task.fields[info]}"),
            console=self.console,
            disable=not self.live,
        )

    def __enter__(self) -> _ProgressDisplay:
        self.bar.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.bar.__exit__(None, None, None)

    def left(self, p: Any) -> str:
        """The time left, from the rate of this call's steps after its first."""
        if self.first_elapsed is None or p.steps_this_call < 2:
            return "ETA ..."
        seconds = (p.elapsed - self.first_elapsed) / (p.steps_this_call - 1) * (p.total - p.done)
        if seconds >= 5400:
            return f"{seconds / 3600:.1f} h left"
        if seconds >= 120:
            return f"{seconds / 60:.0f} min left"
        return f"{seconds:.0f} s left"

    def update(self, p: Any) -> None:
        r = p.record
        self.reached = r
        if self.first_elapsed is None:
            self.first_elapsed = p.elapsed
        left = self.left(p)
        info = f"t {r.t:.4f} s  Nc {r.nc}  it {r.iterations}  ccp {r.ccp_residual:.1e}"
        if self.live:
            if self.task is None:
                self.task = self.bar.add_task(
                    "run", total=p.total, completed=p.done, info=info, left=left
                )
            self.bar.update(self.task, completed=p.done, total=p.total, info=info, left=left)
            return
        now = time.perf_counter()
        if now - self.last_line >= self.EVERY or p.done == p.total:
            self.last_line = now
            self.console.print(f"step {p.done}/{p.total}  {left}  {info}", highlight=False)


@export_app.command("vtu")
def export_vtu_command(
    run_file: Annotated[Path, typer.Argument(help="A run file (run.h5) of `cocd run`.")],
    every: Annotated[int, typer.Option("--every", help="Export one frame in EVERY.")] = 1,
    out: Annotated[
        Path | None, typer.Option("--out", help="Output folder (default: RUN_FILE's, vtu/).")
    ] = None,
    force: Annotated[
        bool, typer.Option("--force", help="Replace a series already in a folder named with --out.")
    ] = False,
) -> None:
    """VTU files per frame and PVD series for ParaView: grains as points, contacts as lines."""
    from cocd.export import VTU_SERIES, export_vtu

    folder = out if out is not None else run_file.parent / "vtu"
    try:
        writable_folder(folder, "--out")
        if out is not None and not force:
            for name in VTU_SERIES:  # the series and their frames
                for path in (folder / f"{name}.pvd", *sorted(folder.glob(f"{name}_*.vtu"))):
                    writable_file(path, "--out")
        paths = export_vtu(run_file, folder, every=every)
    except CocdError as exc:
        fail(exc)
        return
    console.print(f"wrote {', '.join(str(p) for p in paths)} (open them in ParaView)")


@export_app.command("fclib")
def export_fclib_command(
    run_file: Annotated[Path, typer.Argument(help="A run file (run.h5) of `cocd run`.")],
    step: Annotated[
        int | None, typer.Option("--step", help="The step to export (default: the last).")
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option("--out", help="Output file (default: step_<STEP>.hdf5 beside RUN_FILE)."),
    ] = None,
    force: Annotated[
        bool, typer.Option("--force", help="Replace an existing output file.")
    ] = False,
) -> None:
    """One step of a run as an FCLib problem, with its answer: taken again from the frame
    before it, for `cocd problem solve` or any FCLib reader."""
    from cocd.runs import export_step

    try:
        path, again, recorded, start = export_step(run_file, step, out, force=force)
    except CocdError as exc:
        fail(exc)
        return
    console.print(
        f"wrote {path}: step {again.step} (t = {again.t:.6g} s), taken again from the frame "
        f"of step {start}: {again.nc} contacts, {again.solver} {again.iterations} iterations "
        f"(the run: {recorded.nc} contacts, {recorded.iterations} iterations)",
        highlight=False,
    )


@app.command("plot")
def plot_command(
    run_file: Annotated[Path, typer.Argument(help="A run file (run.h5) of `cocd run`.")],
    kind: Annotated[str, typer.Argument(help="profiles, front, energy, stats, snapshot or movie.")],
    out: Annotated[
        Path | None,
        typer.Option(
            "--out", help="Output file (default: KIND.png beside RUN_FILE; movie.gif, or .mp4)."
        ),
    ] = None,
    frame: Annotated[
        int | None,
        typer.Option("--frame", help="Frame of a snapshot (default the last; -1 the last)."),
    ] = None,
    force: Annotated[
        bool, typer.Option("--force", help="Replace an output file named with --out.")
    ] = False,
) -> None:
    """Draw a figure of a run: profiles, front, energies, step statistics, the grains, a movie."""
    from cocd.plots import KINDS, plot_run, plot_target

    try:
        if out is not None and kind in KINDS:  # the file written, its suffix added
            writable_file(plot_target(run_file, kind, out), "--out", replace=force)
        path = plot_run(run_file, kind, out, frame=frame)  # says the path it wrote
    except CocdError as exc:
        fail(exc)
        return
    console.print(f"wrote {path}")


@app.command("show")
def show_command(
    scene: Annotated[Path, typer.Argument(help="Scene file (TOML, see examples/).")],
    out: Annotated[
        Path | None,
        typer.Option("--out", help="PNG file (default: cocd-runs/<scene name>/scene.png)."),
    ] = None,
    force: Annotated[
        bool, typer.Option("--force", help="Replace an output file named with --out.")
    ] = False,
) -> None:
    """The scene before any step: one summary line and a snapshot (PNG)."""
    import numpy as np

    from cocd.config import build_scene, load_config
    from cocd.contacts import detect_contacts

    try:
        config = load_config(scene)
        from cocd.plots import figure_path

        target = figure_path(out if out is not None else Path("cocd-runs") / scene.stem / "scene")
        writable_file(target, "--out", replace=force or out is None)
        built = build_scene(config, str(scene))
        stepper = config.stepper(built)
        contacts = detect_contacts(
            built, stepper.d_max, velocities=built.velocities, dt=config.run.dt, skin=stepper.skin
        )
    except CocdError as exc:
        fail(exc)
        return
    free = ~np.asarray(built.fixed, dtype=bool)
    lo = (built.positions - built.radii[:, None]).min(axis=0)
    hi = (built.positions + built.radii[:, None]).max(axis=0)
    axes = "xyz" if built.dim == 3 else "xy"
    domain = ", ".join(f"{a} [{lo[k]:.4g}, {hi[k]:.4g}]" for k, a in enumerate(axes))
    mass_unit = "kg" if built.dim == 3 else "kg per metre of depth"
    d_mean = 2.0 * float(built.radii[free].mean()) if free.any() else float("nan")
    nc = int(contacts.i.size)
    line = (
        f"{scene.stem}: {built.n_grains} grains, {int(free.sum())} free and "
        f"{int((~free).sum())} glued; domain {domain} m; total mass of the free grains "
        f"{float(built.masses[free].sum()):.4g} {mass_unit}; mean diameter "
        f"{1e3 * d_mean:.4g} mm; {nc} potential contacts "
        f"({nc / max(int(free.sum()), 1):.2f} per free grain)"
    )
    from cocd.plots import plot_scene

    plot_scene(built, target, title=f"{scene.stem}: {config.builder}, before the first step")
    console.print(line, highlight=False)
    console.print(f"wrote {target}", highlight=False)


@app.command("builders")
def builders_command() -> None:
    """Every scene builder a scene file may name, with its parameters and defaults."""
    import inspect

    from cocd.config import BUILDERS

    for name, fn in BUILDERS.items():
        doc = inspect.getdoc(fn) or ""
        console.print(f"[bold]{name}[/bold]: {doc.splitlines()[0] if doc else ''}")
        described = _parameter_docs(doc)
        for p in inspect.signature(fn).parameters.values():
            if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
                continue
            default = "required" if p.default is p.empty else f"default {p.default!r}"
            text = described.get(p.name, "")
            console.print(
                f"  {p.name} ({default}){': ' + text if text else ''}",
                highlight=False,
                markup=False,
            )


def _parameter_docs(doc: str) -> dict[str, str]:
    """First sentence of each parameter's description in a numpydoc docstring."""
    import re

    out: dict[str, str] = {}
    lines = doc.splitlines()
    try:
        start = lines.index("Parameters") + 2
    except ValueError:
        return out
    names: list[str] = []
    text: list[str] = []
    for line in lines[start:]:
        if line and not line.startswith(" "):
            if re.fullmatch(r"-+", line) or line in ("Returns", "Raises", "Notes"):
                break
            for n in names:
                out[n] = " ".join(text).split(". ")[0].rstrip(".")
            names = [n.strip() for n in line.split(":")[0].split(",")]
            text = [line.split(":", 1)[1].strip()] if ":" in line else []
            text = [f"({text[0]})"] if text else []
        elif line.strip():
            text.append(line.strip())
    for n in names:
        out[n] = " ".join(text).split(". ")[0].rstrip(".")
    return out


@app.command("sweep")
def sweep_command(
    sweep_file: Annotated[Path, typer.Argument(help="Sweep file (TOML): scenes and grid axes.")],
    workers: Annotated[
        int | None,
        typer.Option("--workers", help="Worker processes of the local cluster (default: cores)."),
    ] = None,
    scheduler: Annotated[
        str | None,
        typer.Option(
            "--scheduler", help="Address of an existing Dask scheduler (tcp://host:8786)."
        ),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option("--out", help="Output folder (default cocd-results/sweeps/<name>)."),
    ] = None,
) -> None:
    """Run a grid of short runs on Dask; one Parquet file per cell; finished cells are skipped."""
    from cocd.sweep import load_sweep, run_sweep

    try:
        if workers is not None and scheduler is not None:
            raise CocdError("give --workers or --scheduler, not both")
        if workers is not None and workers < 1:
            raise CocdError(f"--workers must be >= 1, got {workers}")
        spec = load_sweep(sweep_file)
        folder = out if out is not None else Path("cocd-results") / "sweeps" / spec.name
        display = _SweepDisplay()
        summary = run_sweep(
            spec, folder, workers=workers, scheduler=scheduler, progress=display.update,
            notice=lambda line: typer.echo(line, err=True),
        )  # fmt: skip
    except CocdError as exc:
        fail(exc)
        return
    if summary.ran == 0:
        console.print(f"{summary.cells} cells, all finished before: nothing to do")
    console.print(
        f"{summary.cells} cells: {summary.ran} run, {summary.skipped} already done, "
        f"{summary.failed} failed; {summary.wall_time:.1f} s; wrote {folder / spec.name}.parquet, "
        f".csv and .md",
        highlight=False,
    )
    if summary.failed:
        typer.echo(
            f"{summary.failed} of {summary.cells} cells failed: their rows hold status "
            "'error' and the message",
            err=True,
        )
        raise typer.Exit(code=EXIT_NOT_SOLVED)


class _SweepDisplay:
    """One line per finished cell (with the count and the rate)."""

    def __init__(self) -> None:
        self.start = time.perf_counter()
        self.first: int | None = None

    def update(self, done: int, total: int, cell: str) -> None:
        if self.first is None:
            self.first = done - 1
        elapsed = time.perf_counter() - self.start
        rate = (done - self.first) / elapsed if elapsed > 0 else float("nan")
        left = (total - done) / rate if rate > 0 else float("nan")
        console.print(
            f"cell {done}/{total} done ({cell}); {rate:.2f} cells/s, {left:.0f} s left",
            highlight=False,
        )


@app.command("solvers")
def list_solvers() -> None:
    """List the registered backends, their capabilities and availability."""
    table = Table("name", "formulation", "dims", "convex", "warm start", "available")
    missing = solvers.unavailable()
    for name, info in sorted(solvers.registered().items()):
        table.add_row(
            name,
            info.formulation,
            ",".join(map(str, info.dims)),
            "yes" if info.convex else "no",
            "yes" if info.warm_start else "no",
            "yes" if name not in missing else f"no: {missing[name]}",
        )
    console.print(table)
