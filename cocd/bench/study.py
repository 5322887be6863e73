"""Studies: each measurement of the harness declared once, its command generated.

A study is a run function and a settings dataclass whose fields are its
options. :func:`register` records it under its group (``bench`` or
``validate``); :func:`command` turns it into a Typer command whose options
come from the fields, so an option's name, default and help are written in
one place. The command runs the study, turns a :class:`~cocd.errors.CocdError`
into a one-line error, and rebuilds ``OUT/README.md`` from the result files'
records.

A field's metadata, set by :func:`option`, says how the command line spells it:
``flag`` (default ``--field-name``), ``help``, ``kind`` for comma-separated
lists (``"floats"``: numbers > 0; ``"numbers"``: any finite numbers;
``"ints"``: integers >= 1; ``"names"``: words), ``argument`` for a
positional argument and ``aliases``, earlier flags that still work.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import typer

from cocd.checks import first_repeat
from cocd.errors import CocdError
from cocd.exits import fail
from cocd.outputs import writable_folder

__all__ = [
    "Study",
    "StudySettings",
    "command",
    "memory_gb",
    "option",
    "parse_list",
    "register",
    "solvers",
    "studies",
    "time_limit",
]

Kind = Literal["floats", "numbers", "ints", "names"]
Group = Literal["bench", "validate"]

#: Where each group writes unless ``--out`` says otherwise (not the committed results/).
DEFAULT_OUT: dict[str, Path] = {
    "bench": Path("cocd-results"),
    "validate": Path("cocd-results/validation"),
}
#: The heading of ``OUT/README.md`` per group.
HEADINGS: dict[str, str | None] = {
    "bench": None,
    "validate": "Validation against the seed papers",
}


def option(
    default: Any,
    help: str,
    *,
    flag: str | None = None,
    kind: Kind | None = None,
    argument: bool = False,
    aliases: tuple[str, ...] = (),
    positive: bool = False,
) -> Any:
    """A settings field with what the command line needs to know of it; ``positive``:
    a number :class:`StudySettings` refuses, before any work, unless finite and > 0
    (``None`` where the field's type admits it, meaning no limit or a default); a list's
    ``kind`` checks its own items, so the two do not go together."""
    if positive and kind is not None:
        raise TypeError(
            f"option {flag or help!r}: positive is for a number; kind {kind!r} "
            "checks a list's items"
        )
    meta = {
        "help": help, "flag": flag, "kind": kind, "argument": argument, "aliases": aliases,
        "positive": positive,
    }  # fmt: skip
    if isinstance(default, list | tuple):
        default = tuple(default)
    if default is dataclasses.MISSING:
        return field(metadata=meta)
    return field(default=default, metadata=meta)


def solvers(default: str | None = None, help: str = "") -> Any:
    """The ``--solvers`` option of a study."""
    return option(default, help or "Comma-separated backends (default: the harness's set).")


def time_limit(default: float) -> Any:
    """The ``--time-limit`` option: seconds per solve."""
    return option(default, "Seconds per solve before a backend is stopped.", positive=True)


def problem_folder() -> Any:
    """The positional ``FOLDER`` of problem files (FCLib HDF5, Siconos text)."""
    return option(
        dataclasses.MISSING, "Folder of FCLib .hdf5 / Siconos .dat problem files.", argument=True
    )


def resume(table: str, help: str = "") -> Any:
    """The ``--resume`` option: keep the rows of ``OUT/<table>.csv`` and solve only the
    others (:class:`cocd.bench.results.Results`)."""
    return option(
        False,
        help or f"Keep the rows already in OUT/{table}.csv (all of them); solve only the others.",
    )


def memory_gb() -> Any:
    """The ``--memory-gb`` option: the memory cap of a backend's child process."""
    return option(None, "Memory cap per backend process (GiB; default 3/4 of RAM).", positive=True)


@dataclass(frozen=True)
class StudySettings:
    """The base of every study's settings dataclass: on creation, from the command line
    or from Python, a field declared ``option(..., positive=True)`` that is not finite
    and > 0 (``None`` aside) is a :class:`~cocd.errors.CocdError` naming its flag."""

    def __post_init__(self) -> None:
        import numbers
        import typing

        hints = typing.get_type_hints(type(self))
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not f.metadata.get("positive"):
                continue
            if value is None and type(None) in typing.get_args(hints[f.name]):
                continue  # the field says what None means (no limit, the default)
            number = (
                float(value)
                if isinstance(value, numbers.Real) and not isinstance(value, bool)
                else math.nan
            )
            if not (math.isfinite(number) and number > 0):
                raise CocdError(f"{_flag(f)} must be a finite number > 0, got {value!r}")
            if hints[f.name] is int and number != int(number):
                raise CocdError(f"{_flag(f)} must be a whole number, got {value!r}")


@dataclass(frozen=True)
class Study:
    """One measurement of the harness.

    Attributes
    ----------
    name : str
        The command's name (``cocd <group> <name>``).
    group : {"bench", "validate"}
        ``bench`` compares backends; ``validate`` reproduces a seed paper's physics.
    settings : type
        A dataclass of the options; :func:`option` declares each field.
    run : callable
        ``run(settings, *, out, progress=print, ...)``: the settings object, the output
        folder, and keywords that are not options (``progress``, test hooks).
    outputs : tuple of str
        The names of the tables it writes under ``out`` (``<name>.csv``,
        ``<name>.md``, ``<name>.meta.json``).
    help : str
        One line for ``--help``; the run function's first docstring line by default.
    aliases : tuple of str
        Older names of the command, kept hidden and marked deprecated.
    hidden : bool
        An old command kept for its users: left out of ``--help``, marked deprecated.
    """

    name: str
    group: Group
    settings: type
    run: Callable[..., object]
    outputs: tuple[str, ...] = ()
    help: str = ""
    aliases: tuple[str, ...] = ()
    hidden: bool = False

    def summary(self) -> str:
        if self.help:
            return self.help
        doc = inspect.getdoc(self.run) or ""
        return doc.split("\n\n")[0].replace("\n", " ")

    def __call__(self, settings: Any = None, *, out: Path | None = None, **changes: Any) -> Any:
        """Run with ``settings`` (default: the declared defaults) changed by ``changes``.

        Keywords that are not settings (``progress``, ...) go to the run function as
        they are.
        """
        settings = self.settings() if settings is None else settings
        names = {f.name for f in dataclasses.fields(settings)}
        extra = {k: v for k, v in changes.items() if k not in names}
        settings = dataclasses.replace(settings, **{k: v for k, v in changes.items() if k in names})
        where = Path(out) if out is not None else DEFAULT_OUT[self.group]
        result = self.run(settings, out=where, **extra)
        self.readme(where, extra.get("progress", print))
        return result

    def readme(self, where: Path, say: Callable[[str], Any] = print) -> Path | None:
        """Rebuild ``where/README.md`` from the records and notes there; None, said, when
        a note names a cell the tables do not hold (the run made other rows than those
        the note was written for): the tables are written all the same."""
        from cocd.bench.report import write_readme

        try:
            return write_readme(where, heading=HEADINGS[self.group])
        except CocdError as exc:
            say(
                f"{where / 'README.md'} not rebuilt: {exc}. The tables are written; "
                f"rebuild it with `cocd bench readme --out {where}` once the notes match them"
            )
            return None


_STUDIES: dict[tuple[str, str], Study] = {}

#: The packages whose modules register studies; :func:`studies` imports each module.
PACKAGES = ("cocd.studies", "cocd.validate")
#: The entry-point group under which other packages name modules that register studies.
ENTRY_POINTS = "cocd.studies"


def register(study: Study) -> Study:
    """Record ``study``; a second study of the same group and name is an error."""
    if not (dataclasses.is_dataclass(study.settings)
            and issubclass(study.settings, StudySettings)):  # fmt: skip
        raise TypeError(f"study {study.name}: settings must be a dataclass of StudySettings")
    key = (study.group, study.name)
    if key in _STUDIES and _STUDIES[key] is not study:
        raise ValueError(f"a {study.group} study named {study.name!r} is already registered")
    _STUDIES[key] = study
    return study


def studies(group: str | None = None) -> list[Study]:
    """The registered studies (of ``group``), in the order their modules were imported.

    Imports every module of :data:`PACKAGES` and those named under the entry-point
    group :data:`ENTRY_POINTS`, so a new study is one module and its
    :func:`register` call.
    """
    import importlib
    import pkgutil
    from importlib.metadata import entry_points

    for package in PACKAGES:
        path = importlib.import_module(package).__path__
        for info in sorted(pkgutil.iter_modules(path), key=lambda m: m.name):
            if not info.name.startswith("_"):
                importlib.import_module(f"{package}.{info.name}")
    for entry in entry_points(group=ENTRY_POINTS):
        try:
            entry.load()
        except Exception as exc:  # another package's study: said, and the rest still work
            import warnings

            warnings.warn(
                f"the study module {entry.value} ({entry.name}) is not loaded: {exc}",
                stacklevel=2,
            )
    return [s for (g, _), s in _STUDIES.items() if group is None or g == group]


def parse_list(text: str, kind: Kind, what: str) -> tuple[Any, ...]:
    """Comma-separated values of ``kind``; a one-line error naming ``what`` otherwise."""
    words = [w.strip() for w in text.split(",") if w.strip()]
    if kind == "names":
        again = first_repeat(words)
        if again is not None:  # it would be run, and tabled, twice
            raise CocdError(f"{what} repeats {words[again]!r}")
        return tuple(words)
    if kind == "ints":
        try:
            ints = tuple(int(w) for w in words)
        except ValueError:
            raise CocdError(f"{what} must be comma-separated integers, got {text!r}") from None
        if any(v < 1 for v in ints):
            raise CocdError(f"{what} must be positive integers, got {text!r}")
        return ints
    try:
        values = tuple(float(w) for w in words)
    except ValueError:
        raise CocdError(f"{what} must be comma-separated numbers, got {text!r}") from None
    if not values:
        raise CocdError(f"{what} is empty")
    if kind == "floats" and any(not (v > 0) for v in values):
        raise CocdError(f"{what} must be positive numbers, got {text!r}")
    if kind == "numbers" and not all(math.isfinite(v) for v in values):
        raise CocdError(f"{what} must be finite numbers, got {text!r}")
    return values


def _flag(f: dataclasses.Field) -> str:
    return f.metadata.get("flag") or "--" + f.name.replace("_", "-")


def _joined(values: Sequence[Any]) -> str:
    return ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in values)


def _parameter(f: dataclasses.Field, hints: dict[str, Any]) -> inspect.Parameter:
    meta = f.metadata
    kind = meta.get("kind")
    default: Any = f.default
    if kind is not None:
        kind_type: Any = str | None if default is None else str
        default = None if default is None else _joined(default)
    else:
        kind_type = hints[f.name]
    info = (
        typer.Argument(help=meta["help"])
        if meta.get("argument")
        else typer.Option(_flag(f), help=meta["help"])
    )
    param_default = inspect.Parameter.empty if default is dataclasses.MISSING else default
    return inspect.Parameter(
        f.name,
        inspect.Parameter.KEYWORD_ONLY,
        default=param_default,
        annotation=Annotated[kind_type, info],
    )


def _alias_parameters(f: dataclasses.Field, hints: dict[str, Any]) -> list[inspect.Parameter]:
    """A hidden parameter per old flag of ``f``, so that the command sees which was given."""
    kind_type: Any = str if f.metadata.get("kind") is not None else hints[f.name]
    return [
        inspect.Parameter(
            _alias_name(f, k),
            inspect.Parameter.KEYWORD_ONLY,
            default=None,
            annotation=Annotated[kind_type | None, typer.Option(alias, hidden=True)],
        )
        for k, alias in enumerate(f.metadata.get("aliases", ()))
    ]


def _alias_name(f: dataclasses.Field, k: int) -> str:
    return f"{f.name}__alias{k}"


def _given(f: dataclasses.Field, kwargs: dict[str, Any], context: Any) -> tuple[Any, str]:
    """The value of ``f`` as given on the command line (``context``, Typer's), under its
    flag or one old flag (popped from ``kwargs``), and that flag; both, or two old flags,
    are refused."""
    value = kwargs[f.name]
    given: list[str] = []
    for k, alias in enumerate(f.metadata.get("aliases", ())):
        old = kwargs.pop(_alias_name(f, k), None)
        if old is not None:
            given.append(alias)
            value = old
    source = None if context is None else context.get_parameter_source(f.name)
    if given and getattr(source, "name", None) == "COMMANDLINE":
        given.insert(0, _flag(f))
    if len(given) > 1:
        raise CocdError(f"{' and '.join(given)} name one option: give one of them")
    return value, given[0] if given else _flag(f)


def _out_help(default: Path) -> str:
    committed = Path("results") / default.relative_to(DEFAULT_OUT["bench"])
    return f"Output directory (the committed tables: --out {committed})."


def command(study: Study, *, name: str | None = None, out: Path | None = None) -> Callable:
    """A Typer command function for ``study``: its options are the settings' fields."""
    import typing

    hints = typing.get_type_hints(study.settings)
    fields = dataclasses.fields(study.settings)
    out_default = out or DEFAULT_OUT[study.group]
    params = [_parameter(f, hints) for f in fields]
    params += [p for f in fields for p in _alias_parameters(f, hints)]
    params.append(inspect.Parameter("context", inspect.Parameter.KEYWORD_ONLY,
                                    default=None, annotation=typer.Context))  # fmt: skip
    params.append(
        inspect.Parameter(
            "out",
            inspect.Parameter.KEYWORD_ONLY,
            default=out_default,
            annotation=Annotated[Path, typer.Option("--out", help=_out_help(out_default))],
        )
    )

    def run_command(**kwargs: Any) -> None:
        where = Path(kwargs.pop("out"))
        context = kwargs.pop("context", None)
        try:
            values = {}
            for f in fields:
                value, flag = _given(f, kwargs, context)
                kind = f.metadata.get("kind")
                if kind is not None and value is not None:
                    value = parse_list(value, kind, flag)
                values[f.name] = value
            writable_folder(where, "--out")
            from cocd.bench.report import check_readme_ours

            check_readme_ours(where)  # before the work, not after it
            study.run(study.settings(**values), out=where)
            if study.readme(where, typer.echo) is not None:
                typer.echo(f"wrote {where / 'README.md'}")
        except CocdError as exc:
            fail(exc)

    run_command.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    run_command.__annotations__ = {p.name: p.annotation for p in params}
    run_command.__name__ = (name or study.name).replace("-", "_")
    run_command.__doc__ = study.summary()
    return run_command


def add_commands(app: typer.Typer, group: Group) -> None:
    """Add a command to ``app`` for each study of ``group``, and the hidden old names."""
    for study in sorted(studies(group), key=lambda s: s.name):
        summary = study.summary()
        app.command(
            study.name,
            help=summary,
            short_help=summary,
            hidden=study.hidden,
            deprecated=study.hidden,
        )(command(study))
        for alias in study.aliases:
            app.command(
                alias,
                help=f"Old name of `cocd {group} {study.name}`.",
                hidden=True,
                deprecated=True,
            )(command(study, name=alias))
