"""The time stepper: detect, assemble, solve, integrate, record.

The stepper is the only place that knows both scenes and backends; it talks
to the backends through :class:`~cocd.problem.ConicProblem` and
:class:`~solvers.Solution` only.
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Callable, Collection, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

import solvers
from cocd.contacts import SKIN_FACTOR, ContactSet, Penetration, detect_contacts, penetration
from cocd.coupling import grain_impulses, resolve_loads
from cocd.errors import PenetrationError, PenetrationWarning, ProblemError
from cocd.measure import kinetic_energy, potential_energy
from cocd.problem import ConicProblem, assemble, scatter_velocity
from cocd.residuals import Residuals
from cocd.scene import DEFAULT_OVERLAP_TOL, Scene
from cocd.step_solve import Acceptance, match_impulses, solve_chain, warm_start

if TYPE_CHECKING:
    import pandas as pd

    from cocd.coupling import ExternalLoads

__all__ = [
    "DEFAULT_PENETRATION_TOL",
    "PENETRATION_POLICIES",
    "StepRecord",
    "Stepper",
    "match_impulses",
]

FloatArray = NDArray[np.float64]

#: Largest overlap allowed at the end of a step, relative to the smaller radius
#: of the pair (1 %); deeper is a penetration, handled by the stepper's policy.
DEFAULT_PENETRATION_TOL = 1e-2
#: What a step whose grains overlap by more than the tolerance does:
#: ``redo`` it with a larger margin for the grains that went through (then
#: ``raise`` if that is not enough, or if the overlapping pair was a potential
#: contact: the backend's answer let it overlap), ``raise`` at once, ``warn``
#: and go on, or only ``record`` it in the statistics (for studies of loose
#: tolerances).
PENETRATION_POLICIES = ("redo", "raise", "warn", "record")


@dataclass(frozen=True)
class StepRecord:
    """Statistics of one step; ``t`` is the time at its end."""

    step: int
    t: float
    n: int
    nc: int
    solver: str
    status: str
    iterations: int
    detect_time: float
    setup_time: float
    solve_time: float
    ccp_residual: float
    coulomb_residual: float
    dynamics_residual: float
    cone_violation_max: float
    complementarity_max: float
    kinetic_energy: float
    potential_energy: float
    #: Backends of the fallback chain that failed this step, with the reason
    #: ("" when the first one answered).
    failures: str = ""
    #: Largest overlap at the end of the step (grains and walls), relative to the
    #: smaller radius of the pair (NaN: not measured, in run files written before).
    penetration: float = float("nan")
    #: Pairs overlapping at the end of the step that were not potential contacts.
    missed_contacts: int = 0
    #: Times the step was redone with a larger margin, and the seconds those took.
    redos: int = 0
    redo_time: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


class Stepper:
    """Advance a scene with one convex contact problem per step.

    At each step: detect potential contacts (gap below ``d_max`` plus a margin
    that follows the free velocities), assemble the :class:`ConicProblem`, solve
    it with the chosen backend, set the velocity to ``u = U + M^-1 H'p`` (the
    velocity the impulses imply, so that momentum is conserved to rounding
    whatever the backend), move the centres by ``dt u`` (symplectic Euler), then
    measure the overlaps at the end of the step (:func:`~cocd.contacts.penetration`)
    and apply the ``on_penetration`` policy.

    Parameters
    ----------
    scene : Scene
        Advanced in place.
    dt : float
        Time step (s).
    solver : str
        Backend name (see :func:`solvers.available`).
    tol : float
        Backend tolerance.
    d_max : float, optional
        Floor of the contact detection threshold (m); default half the mean
        radius. A pair is a potential contact when its gap is below ``d_max``
        plus a margin that follows the motion (:func:`~cocd.contacts.detect_contacts`):
        ``skin`` times the distance its free relative velocity closes in ``dt``.
    skin : float, optional
        Margin factor; default :data:`~cocd.contacts.SKIN_FACTOR` when ``d_max``
        is not given, and 0 when it is (a user's ``d_max`` is the threshold; the
        end-of-step check still applies).
    penetration_tol : float
        Largest overlap allowed at the end of a step, relative to the smaller
        radius of the pair (default :data:`DEFAULT_PENETRATION_TOL`, 1 %). Every
        step measures it (``penetration``, ``missed_contacts`` in the statistics).
    on_penetration : {"redo", "raise", "warn", "record"}
        What a step whose grains overlap by more does. ``redo`` (default): take
        the step again with the margin of the grains that went through widened
        to their gap (at most ``max_redos`` times); if grains still overlap, or
        the pair was a potential contact (the backend's answer let it overlap:
        tighten ``tol``), raise. ``raise``: :class:`PenetrationError` naming the
        step, the pair and the depth. ``warn``: a :class:`PenetrationWarning`, and
        the run goes on. ``record``: only the statistics say so.
    max_redos : int
        Redos allowed per step under ``redo``.
    warm_start : bool
        Start backends that accept one from the previous step's impulses,
        matched by contact pair.
    max_iter, time_limit : optional
        Passed to the backend.
    solver_options : dict, optional
        Backend-specific options.
    overlap_tol : float
        Largest initial overlap allowed, relative to the smaller radius.
    fclib_dir : path, optional
        Write step problems to this folder as FCLib global problems
        (``step_000001.hdf5``, ...) with the step's answer in ``/solution``,
        so that other tools can solve cocd's steps (:mod:`cocd.io.fclib`).
    fclib_steps : collection of int, optional
        Which step numbers (1-based) to write; every step when ``None``.
    fallback : sequence of str
        The failure policy. Empty (default): a failed step raises
        :class:`SolverError` naming the step and the backend. Otherwise the
        backends tried in turn when the one before fails; the statistics record
        which backend answered (``solver``) and why the others failed
        (``failures``); when every one fails, :class:`SolverError` names them all.
    external : Loads, array, (forces, torques) or callable, optional
        External loads on the grains (:mod:`cocd.coupling`): fixed, or a
        callable ``f(scene, t)`` called at the start of every step (``t``: the
        time then) returning them; e.g. the drag and buoyancy of a fluid
        solver. :meth:`contact_impulses` gives such a solver the contact
        impulses per grain of the last step.
    residual_factor : float or None
        A step fails when its residual (``ccp_residual``; ``coulomb_residual``
        for the non-convex backends) is above ``residual_factor * tol``
        (default 1000; ``None``: not checked). Not checked for the answers of
        approximate models (``extras["approximation"]``, e.g. faceted cones).
    energy_factor : float or None
        A step fails when the kinetic energy after it is above
        ``energy_factor`` times the larger of the energy before it and the
        energy of the free velocity ``U`` (default 100: a blow-up; ``None``:
        not checked). Non-finite velocities or impulses always fail.
    """

    def __init__(
        self,
        scene: Scene,
        dt: float,
        *,
        solver: str = "clarabel",
        tol: float = 1e-8,
        d_max: float | None = None,
        skin: float | None = None,
        penetration_tol: float = DEFAULT_PENETRATION_TOL,
        on_penetration: str = "redo",
        max_redos: int = 3,
        warm_start: bool = True,
        max_iter: int | None = None,
        time_limit: float | None = None,
        solver_options: dict[str, Any] | None = None,
        overlap_tol: float = DEFAULT_OVERLAP_TOL,
        fclib_dir: str | os.PathLike[str] | None = None,
        fclib_steps: Collection[int] | None = None,
        fallback: Sequence[str] = (),
        external: ExternalLoads | None = None,
        residual_factor: float | None = 1e3,
        energy_factor: float | None = 100.0,
    ) -> None:
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a Scene, got {type(scene).__name__}")
        try:
            dt = float(dt)
            tol = float(tol)
        except (TypeError, ValueError):
            raise ProblemError(f"dt and tol must be numbers, got {dt!r} and {tol!r}") from None
        if not (np.isfinite(dt) and dt > 0.0):
            raise ProblemError(f"time step dt must be finite and > 0, got {dt}")
        if not (np.isfinite(tol) and tol > 0.0):
            raise ProblemError(f"tol must be finite and > 0, got {tol}")
        if isinstance(fallback, str):
            fallback = [name for name in fallback.split(",") if name]
        self.fallback = tuple(fallback)
        self.solver_options = dict(solver_options or {})
        for key in ("problem", "solver", "tol", "warm_start", "max_iter", "time_limit"):
            if key in self.solver_options:
                raise ProblemError(
                    f"solver_options cannot set {key!r}, which the stepper gives the backend"
                )
        for k, name in enumerate((solver, *self.fallback)):
            # Unknown options and options of the wrong kind fail here too (the options go
            # to the first backend only).
            info, _, _ = solvers.requested(name, {}, {} if k else self.solver_options)
            if k == 0:
                self.info = info  # unknown names fail here, before any work
            if scene.dim not in info.dims:
                raise ProblemError(
                    f"solver {name!r} handles dimensions {info.dims}, not a {scene.dim}D scene"
                )
        for label, factor in (
            ("residual_factor", residual_factor),
            ("energy_factor", energy_factor),
        ):
            if factor is not None and not (np.isfinite(factor) and factor >= 1.0):
                raise ProblemError(f"{label} must be a finite number >= 1 or None, got {factor}")
        self.residual_factor = residual_factor
        self.energy_factor = energy_factor
        scene.check_overlaps(overlap_tol)
        self.external = external
        #: A fixed load, checked and converted once.
        self._fixed_loads = (
            resolve_loads(external, scene) if not callable(external) else (None, None)
        )
        self.scene = scene
        self.dt = dt
        self.solver = solver
        self.tol = tol
        if d_max is not None:
            try:
                d_max = float(d_max)
            except (TypeError, ValueError):
                raise ProblemError(f"d_max must be a number, got {d_max!r}") from None
            if not (np.isfinite(d_max) and d_max >= 0.0):
                raise ProblemError(f"d_max must be finite and >= 0, got {d_max}")
        skin = (SKIN_FACTOR if d_max is None else 0.0) if skin is None else skin
        for label, value in (("skin", skin), ("penetration_tol", penetration_tol)):
            if not (isinstance(value, int | float) and np.isfinite(value) and value >= 0.0):
                raise ProblemError(f"{label} must be a finite number >= 0, got {value!r}")
        if on_penetration not in PENETRATION_POLICIES:
            raise ProblemError(
                f"on_penetration must be one of {', '.join(PENETRATION_POLICIES)}, "
                f"got {on_penetration!r}"
            )
        if not (isinstance(max_redos, int) and max_redos >= 0):
            raise ProblemError(f"max_redos must be an integer >= 0, got {max_redos!r}")
        self.d_max = d_max
        self.skin = float(skin)
        self.penetration_tol = float(penetration_tol)
        self.on_penetration = on_penetration
        self.max_redos = max_redos
        #: The last step's end-of-step overlaps.
        self.penetration: Penetration | None = None
        self.warm_start = warm_start and self.info.warm_start
        self.max_iter = max_iter
        self.time_limit = time_limit
        self.fclib_dir = None if fclib_dir is None else Path(fclib_dir)
        self.fclib_steps = None if fclib_steps is None else frozenset(int(k) for k in fclib_steps)
        if self.fclib_dir is not None:
            self.fclib_dir.mkdir(parents=True, exist_ok=True)
        self.records: list[StepRecord] = []
        self.contacts: ContactSet | None = None
        self.problem: ConicProblem | None = None
        self.solution: solvers.Solution | None = None
        #: The last step's contact keys and impulses: the next step's warm start.
        self.previous: tuple[NDArray[np.int64], FloatArray] | None = None

    def restore(
        self,
        records: list[StepRecord],
        previous: tuple[NDArray[np.int64], FloatArray] | None,
    ) -> None:
        """Continue a run: the steps taken so far and the last step's contact keys and
        impulses (the warm start of the next step), e.g. read from a run file.

        With the scene in the state it had after those steps, the next steps
        are those the uninterrupted run would have taken.
        """
        self.records = list(records)
        self.previous = None if previous is None else (previous[0], previous[1])

    @property
    def step_count(self) -> int:
        return len(self.records)

    def step(self) -> StepRecord:
        """Advance the scene by one time step and return its statistics."""
        scene = self.scene
        k = self.step_count + 1
        forces, torques = self._loads(k)
        saved = (scene.positions.copy(), scene.velocities.copy(), scene.angular_velocities.copy())
        t_start = scene.time
        free_velocity = self._free_velocity(forces)
        energy_before = kinetic_energy(scene)
        reach: FloatArray | None = None
        redos, redo_time = 0, 0.0
        warm = self.previous
        while True:
            attempt = time.perf_counter()
            contacts, problem, solution, answered, failures, res, detect_time = self._solve(
                k, forces, torques, free_velocity, reach, energy_before, warm
            )
            check = time.perf_counter()
            pen = penetration(scene, contacts, saved[0])
            detect_time += time.perf_counter() - check
            if pen.depth <= self.penetration_tol or self.on_penetration == "record":
                break
            where = f"step {k} (t = {scene.time:.6g} s, {problem.nc} contacts)"
            redo = (
                self.on_penetration == "redo"
                and pen.missed_depth > self.penetration_tol
                and redos < self.max_redos
            )
            if redo:
                # Widen the margin of the grains that went through to the gaps they
                # closed: those pairs, and their grains' other neighbours as near,
                # are potential contacts of the step taken again.
                reach = np.zeros(scene.n_grains) if reach is None else reach
                for i, j, g in zip(pen.missed_i, pen.missed_j, pen.missed_gap, strict=True):
                    reach[i] = max(reach[i], g)
                    if j >= 0:
                        reach[j] = max(reach[j], g)
                self._restore(saved, t_start)
                redos += 1
                redo_time += time.perf_counter() - attempt
                # The step taken again starts from this attempt's impulses: its contacts
                # are the same but for the few the wider margin adds.
                warm = (contacts.keys, solution.p)
                continue
            message = f"{where}: {pen.describe(scene)}, above {self.penetration_tol:g}"
            if self.on_penetration == "warn":
                warnings.warn(message, PenetrationWarning, stacklevel=2)
                break
            self._restore(saved, t_start)
            if pen.potential:
                message += (
                    f": the answer of {answered} (tol {self.tol:g}) lets it overlap; tighten tol"
                )
            elif redos:
                message += f" after {redos} redos with a wider margin"
            else:
                message += (
                    f": its gap was above d_max ({contacts.d_max:.3g} m) plus its margin; "
                    "widen d_max or skin, or let the step be redone (on_penetration='redo')"
                )
            raise PenetrationError(message)

        record = StepRecord(
            step=k,
            t=scene.time,
            n=scene.n_free,
            nc=problem.nc,
            solver=answered,
            status=solution.status.value,
            iterations=solution.iterations,
            detect_time=detect_time,
            setup_time=solution.setup_time,
            solve_time=solution.solve_time,
            ccp_residual=res.ccp,
            coulomb_residual=res.coulomb,
            dynamics_residual=res.dynamics,
            cone_violation_max=res.cone_violation_max,
            complementarity_max=res.complementarity_max,
            kinetic_energy=kinetic_energy(scene),
            potential_energy=potential_energy(scene),
            failures="; ".join(failures),
            penetration=pen.depth,
            missed_contacts=pen.missed,
            redos=redos,
            redo_time=redo_time,
        )
        self.contacts, self.problem, self.solution = contacts, problem, solution
        self.penetration = pen
        self.previous = (contacts.keys, solution.p)
        self.records.append(record)
        if self.fclib_dir is not None and (self.fclib_steps is None or k in self.fclib_steps):
            self.export_step(self.fclib_dir / f"step_{k:06d}.hdf5")
        return record

    def _solve(
        self,
        k: int,
        forces: FloatArray | None,
        torques: FloatArray | None,
        free_velocity: FloatArray,
        reach: FloatArray | None,
        energy_before: float,
        warm: tuple[NDArray[np.int64], FloatArray] | None,
    ) -> tuple[ContactSet, ConicProblem, solvers.Solution, str, list[str], Residuals, float]:
        """Detect, assemble, solve (along the fallback chain) and move the grains.

        ``warm``: contact keys and impulses to warm-start from (the last step's, or a
        redone attempt's), when :attr:`warm_start`. Returns the contacts, the problem,
        the accepted answer, the backend that gave it, the failures before it, its
        residuals and the detection time.
        """
        scene = self.scene
        start = time.perf_counter()
        contacts = detect_contacts(
            scene, self.d_max, velocities=free_velocity, dt=self.dt, skin=self.skin, reach=reach
        )
        problem = assemble(scene, contacts, self.dt, forces=forces, torques=torques)
        detect_time = time.perf_counter() - start

        p0 = warm_start(warm if self.warm_start else None, contacts.keys, problem.contact_dim)
        where = f"step {k} (t = {scene.time + self.dt:.6g} s, {problem.nc} contacts)"
        solution, name, failures, res = solve_chain(
            problem,
            (self.solver, *self.fallback),
            Acceptance(self.tol, self.residual_factor, self.energy_factor),
            energy_before,
            where,
            p0=p0,
            options=self.solver_options,
            max_iter=self.max_iter,
            time_limit=self.time_limit,
        )

        scatter_velocity(scene, problem.velocity(solution.p), problem.contact_dim == 1)
        free = scene.free
        if torques is not None and problem.contact_dim == 1:
            # Frictionless: no contact acts on the rotations, the torque alone does.
            scene.angular_velocities[free] += (
                self.dt * torques[free] / _rotational_inertia(scene)[free]
            )
        scene.positions[free] += self.dt * scene.velocities[free]
        scene.time += self.dt
        return contacts, problem, solution, name, failures, res, detect_time

    def _free_velocity(self, forces: FloatArray | None) -> FloatArray:
        """Translational free velocities ``v + dt (g + F / m)``, shape ``(n, d)``."""
        scene = self.scene
        accel = np.broadcast_to(scene.gravity, scene.velocities.shape)
        if forces is not None:
            accel = accel + forces / scene.masses[:, None]
        return np.asarray(scene.velocities + self.dt * accel)

    def _restore(self, saved: tuple[FloatArray, FloatArray, FloatArray], t: float) -> None:
        """Put the scene back in the state it had at the start of the step."""
        scene = self.scene
        scene.positions[...] = saved[0]
        scene.velocities[...] = saved[1]
        scene.angular_velocities[...] = saved[2]
        scene.time = t

    def _loads(self, k: int) -> tuple[FloatArray | None, FloatArray | None]:
        """The external loads of step ``k``, checked."""
        ext = self.external
        if not callable(ext):
            return self._fixed_loads
        where = f"external loads of step {k} (t = {self.scene.time:.6g} s)"
        try:
            ext = ext(self.scene, self.scene.time)
        except ProblemError:
            raise
        except Exception as exc:
            raise ProblemError(f"{where}: the load callable raised {exc!r}") from exc
        return resolve_loads(ext, self.scene, where)

    def contact_impulses(self) -> tuple[FloatArray, FloatArray]:
        """Net contact impulse (N s, ``(n, d)``) and angular impulse about the centre
        (N m s, ``(n,)`` in 2D, ``(n, 3)`` in 3D) on each grain in the last step.

        Divide by ``dt`` for mean contact forces and torques. Fixed grains get
        zeros. Raises :class:`ProblemError` before the first step.
        """
        if self.problem is None or self.solution is None:
            raise ProblemError("no step has been taken yet: no contact impulses")
        return grain_impulses(self.scene, self.problem, self.solution.p)

    def export_step(self, path: str | os.PathLike[str]) -> Path:
        """Write the last step's problem, with its answer, as an FCLib global problem.

        ``M = diag(mass)``, ``H = H_cocd'``, ``f = M U``, ``w = (D/dt, 0)`` (see
        :meth:`cocd.io.problems.GlobalProblem.from_conic`); ``/solution`` holds
        ``r`` (impulses), ``u`` (relative velocities) and ``v`` (velocities).
        """
        from cocd.io.fclib import write_fclib
        from cocd.io.problems import GlobalProblem

        if self.problem is None or self.solution is None:
            raise ProblemError("no step has been taken yet: nothing to export")
        problem, k = self.problem, self.step_count
        scene = self.scene
        glob = GlobalProblem.from_conic(
            problem,
            title=f"cocd {scene.dim}D step {k}",
            description=(
                f"cocd step {k} (t = {scene.time:.9g} s, dt = {self.dt:g} s): "
                f"{scene.n_free} free grains, {problem.nc} contacts; solved by "
                f"{self.solver} at tol {self.tol:g}. Velocities in the problem's "
                "unknowns (translations, then rotations times radius)."
            ),
        )
        p = self.solution.p
        if problem.contact_dim == 1:  # written with zero tangential components
            p = np.concatenate([p, np.zeros((problem.nc, scene.dim - 1))], axis=1)
        return write_fclib(path, glob, solution=glob.solution(p))

    def run(
        self,
        n_steps: int | None = None,
        *,
        until: float | None = None,
        callback: Callable[[StepRecord], None] | None = None,
    ) -> list[StepRecord]:
        """Take ``n_steps`` steps, or step until the time reaches ``until``.

        Returns the records of the steps taken by this call.
        """
        if (n_steps is None) == (until is None):
            raise ProblemError("give exactly one of n_steps and until")
        if n_steps is None:
            assert until is not None
            n_steps = max(0, int(np.ceil((until - self.scene.time) / self.dt - 1e-9)))
        if n_steps < 0:
            raise ProblemError(f"n_steps must be >= 0, got {n_steps}")
        taken = []
        for _ in range(n_steps):
            record = self.step()
            taken.append(record)
            if callback is not None:
                callback(record)
        return taken

    def stats(self) -> pd.DataFrame:
        """Every step's record as a pandas table, one row per step."""
        import pandas as pd

        columns = list(StepRecord.__dataclass_fields__)
        return pd.DataFrame([r.as_dict() for r in self.records], columns=columns)


def _rotational_inertia(scene: Scene) -> FloatArray:
    inertia = scene.inertia
    return inertia if scene.dim == 2 else inertia[:, None]
