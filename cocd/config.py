"""Scene files: a TOML description of a run, validated, and the scene it builds.

A scene file names a builder of :mod:`cocd.builders` with its arguments and the
run's parameters::

    builder = "column_collapse"          # a function of cocd.builders

    [params]                             # its keyword arguments
    dim = 2
    n_grains = 300
    mu = 0.3

    [run]
    dt = 1e-3                            # time step (s)
    until = 0.2                          # simulated time at the end (s)
    solver = "clarabel"                  # see `cocd solvers`
    tol = 1e-8
    frame_every = 10                     # steps between saved frames
    warm_start = true
    fallback = ["clarabel"]              # backends tried in turn when a step fails
    residual_factor = 1000               # a step fails above this multiple of tol
    energy_factor = 100                  # ... or when its kinetic energy blows up
    d_max = 5e-4                         # detection floor (m); default half the mean radius
    skin = 2                             # margin factor (default 2; 0 when d_max is given)
    penetration_tol = 0.01               # end-of-step overlap allowed, in radii
    on_penetration = "redo"              # or "raise", "warn", "record"
    [run.solver_options]                 # backend options, passed as they are

Every key is checked (pydantic): an unknown key, a value of the wrong type or
out of range gives a :class:`ConfigError` whose message names the file, the key
and the reason, in one line. Builder arguments are checked against the
builder's signature, then by the builder itself (negative sizes, ...).
"""

from __future__ import annotations

import inspect
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import pydantic
import tomllib
from pydantic import BaseModel, ConfigDict, Field, field_validator

from cocd import builders
from cocd.checks import argument_checker
from cocd.errors import CocdError
from cocd.scene import DEFAULT_OVERLAP_TOL, Scene
from cocd.stepper import DEFAULT_PENETRATION_TOL

if TYPE_CHECKING:
    from cocd.stepper import Stepper

__all__ = [
    "BUILDERS",
    "DEFAULT_CONFIG",
    "ConfigError",
    "RunConfig",
    "RunSection",
    "build_scene",
    "builder_defaults",
    "load_config",
    "parse_config",
    "same_params",
]

#: The builders a scene file may name.
BUILDERS: dict[str, Callable[..., Scene]] = {
    name: getattr(builders, name)
    for name in (
        "column_2d",
        "column_collapse",
        "stack",
        "box_3d",
        "static_box",
        "heavy_on_light",
        "tall_stack",
        "jammed_box",
        "wedged_grain",
        "fast_impact",
        "size_ratio",
        "zero_gap",
    )
}


def known_builder(name: str) -> str:
    """``name`` if it is a builder of :data:`BUILDERS` (pydantic validators call it)."""
    if name not in BUILDERS:
        raise ValueError(f"unknown builder {name!r}; one of {', '.join(sorted(BUILDERS))}")
    return name


class ConfigError(CocdError, ValueError):
    """A scene file is missing, unreadable or invalid; the message names the key."""


class RunSection(BaseModel):
    """The ``[run]`` table: how to advance the scene and what to save."""

    model_config = ConfigDict(extra="forbid", strict=False)

    dt: float = Field(1e-3, gt=0.0, description="time step (s)")
    until: float | None = Field(None, gt=0.0, description="simulated time at the end (s)")
    steps: int | None = Field(None, ge=0, description="number of steps (instead of until)")
    solver: str = Field("clarabel", description="backend (see `cocd solvers`)")
    tol: float = Field(1e-8, gt=0.0, description="tolerance: optimal means ccp_residual <= tol")
    frame_every: int = Field(10, ge=1, description="steps between saved frames")
    warm_start: bool = Field(True, description="start each step from the last impulses")
    max_iter: int | None = Field(None, ge=1, description="backend iteration cap")
    solver_options: dict[str, Any] = Field(
        default_factory=dict, description="options passed to the backend"
    )
    fallback: list[str] = Field(default_factory=list, description="backends tried on failure")
    residual_factor: float | None = Field(
        1e3, ge=1.0, description="a step fails above residual_factor x tol"
    )
    energy_factor: float | None = Field(
        100.0, ge=1.0, description="a step fails above this times the kinetic energy before it"
    )
    d_max: float | None = Field(
        None, ge=0.0, description="floor of the detection threshold (m); default r_mean / 2"
    )
    skin: float | None = Field(
        None, ge=0.0, description="margin factor; default 2 without d_max, 0 with it"
    )
    penetration_tol: float = Field(
        DEFAULT_PENETRATION_TOL, ge=0.0, description="end-of-step overlap allowed (radii)"
    )
    on_penetration: Literal["redo", "raise", "warn", "record"] = Field(
        "redo", description="what an overlap above penetration_tol does"
    )

    @field_validator("dt", "until", "tol", "d_max", "skin", "penetration_tol")
    @classmethod
    def _finite(cls, value: float | None) -> float | None:
        if value is not None and not math.isfinite(value):
            raise ValueError("must be finite")
        return value


class RunConfig(BaseModel):
    """A whole scene file: the builder, its arguments and the ``[run]`` table."""

    model_config = ConfigDict(extra="forbid")

    builder: str
    params: dict[str, Any] = Field(default_factory=dict)
    run: RunSection = Field(default_factory=lambda: RunSection.model_validate({}))

    _known_builder = field_validator("builder")(classmethod(lambda cls, v: known_builder(v)))

    def stepper(self, scene: Scene, *, resumed: bool = False) -> Stepper:
        """A :class:`~cocd.stepper.Stepper` of ``scene`` with the ``[run]`` parameters.

        ``resumed``: ``scene`` is a state the run itself reached, whose small
        overlaps are its solver's (within its tolerance): they are not checked
        against the limit set for initial scenes.
        """
        from cocd.stepper import Stepper

        rc = self.run
        return Stepper(
            scene,
            rc.dt,
            solver=rc.solver,
            tol=rc.tol,
            warm_start=rc.warm_start,
            max_iter=rc.max_iter,
            solver_options=rc.solver_options,
            fallback=rc.fallback,
            residual_factor=rc.residual_factor,
            energy_factor=rc.energy_factor,
            d_max=rc.d_max,
            skin=rc.skin,
            penetration_tol=rc.penetration_tol,
            on_penetration=rc.on_penetration,
            overlap_tol=math.inf if resumed else DEFAULT_OVERLAP_TOL,
        )

    def n_steps(self, start_time: float = 0.0) -> int:
        """Steps from ``start_time`` to the end (``until``, else ``steps``, else 100)."""
        run = self.run
        if run.until is not None:
            return max(0, math.ceil((run.until - start_time) / run.dt - 1e-9))
        return 100 if run.steps is None else run.steps

    def resolved(self) -> dict[str, Any]:
        """The configuration with every default filled in (builder defaults too), as JSON data."""
        params = builder_defaults(self.builder)
        params.update(self.params)
        data = self.model_dump()
        data["params"] = params
        return json.loads(json.dumps(data, default=str))


def builder_defaults(builder: str) -> dict[str, Any]:
    """The keyword defaults of builder ``builder`` (JSON data; empty for an unknown one)."""
    make = BUILDERS.get(builder)
    if make is None:
        return {}
    signature = inspect.signature(make)
    defaults = {
        name: p.default
        for name, p in signature.parameters.items()
        if p.default is not inspect.Parameter.empty
    }
    return dict(json.loads(json.dumps(defaults, default=str)))


def same_params(builder: str, old: dict[str, Any], new: dict[str, Any]) -> bool:
    """Whether two resolved ``params`` of ``builder`` make the same scene.

    A parameter that one side lacks counts as the builder's default: a run file or
    kept measurement written before a builder gained a parameter (whose default keeps
    the old scene) still matches the same scene resolved today.
    """
    defaults = builder_defaults(builder)
    missing = object()
    for key in set(old) | set(new):
        a, b = old.get(key, defaults.get(key, missing)), new.get(key, defaults.get(key, missing))
        if a is missing or b is missing or a != b:
            return False
    return True


#: The scene of ``cocd run`` without a scene file: a small 2D column collapse.
DEFAULT_CONFIG: dict[str, Any] = {
    "builder": "column_2d",
    "params": {"n_grains": 300, "mu": 0.3},
    "run": {"dt": 1e-3, "until": 0.1, "solver": "clarabel", "tol": 1e-8, "frame_every": 10},
}


def _where(loc: tuple[Any, ...]) -> str:
    return ".".join(str(part) for part in loc) or "(top level)"


def parse_config(data: Any, source: str = "scene file", *, params: bool = True) -> RunConfig:
    """Validate a scene file's content (a dict, as read from TOML).

    ``params=False`` leaves the builder's arguments unchecked: a run file's own
    configuration, whose frames hold the scene it built (a builder may have gained
    arguments since)."""
    try:
        config = RunConfig.model_validate(data)
    except pydantic.ValidationError as exc:
        first = exc.errors()[0]
        loc = _where(first["loc"])
        more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
        message = str(first["msg"]).removeprefix("Value error, ")
        if first["type"] == "extra_forbidden":
            message = "unknown key"
        raise ConfigError(f"{source}: {loc}: {message}{more}") from None
    if params:
        _check_params(config, source)
    return config


def _check_params(config: RunConfig, source: str) -> None:
    """The builder's arguments against its signature: names first, then types."""
    builder = BUILDERS[config.builder]
    signature = inspect.signature(builder)
    for key in config.params:
        if key not in signature.parameters:
            known = ", ".join(signature.parameters)
            raise ConfigError(
                f"{source}: params.{key}: unknown argument of {config.builder} (known: {known})"
            )
    try:
        argument_checker(builder)(**config.params)
    except pydantic.ValidationError as exc:
        first = exc.errors()[0]
        loc = ".".join(str(part) for part in first["loc"] if not isinstance(part, int))
        message = str(first["msg"]).removeprefix("Value error, ")
        raise ConfigError(f"{source}: params.{loc}: {message}") from None


def load_config(path: str | Path) -> RunConfig:
    """Read and validate a scene file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"scene file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read scene file {path}: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    return parse_config(data, str(path))


def build_scene(config: RunConfig, source: str = "scene file") -> Scene:
    """The scene the configuration's builder makes from its arguments.

    The builder's own checks (negative sizes, overlaps, ...) become a
    :class:`ConfigError` naming the file and the builder.
    """
    try:
        return BUILDERS[config.builder](**config.params)
    except (CocdError, TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: params of {config.builder}: {exc}") from None
