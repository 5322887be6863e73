"""Output places, checked before any work: a run folder that would lose a run, or a
folder or file that cannot be written, is a one-line error."""

from __future__ import annotations

from pathlib import Path

from cocd.errors import CocdError


def check_run_folder(folder: Path, *, resume: bool, force: bool) -> None:
    """Refuse, before any work, a run folder that would lose a run or cannot be written."""
    from cocd.runs import RUN_FILE, existing_run, holds_no_step

    path = folder / RUN_FILE
    if folder.exists() and not folder.is_dir():
        raise CocdError(f"--out {folder} is a file, not a folder")
    if path.is_dir():
        raise CocdError(f"--out {folder}: {RUN_FILE} there is a folder, not a run file")
    if resume and not path.exists():
        raise CocdError(
            f"no run to resume in {folder} (no {RUN_FILE}); leave out --resume to start one"
        )
    if path.exists() and not (resume or force or holds_no_step(path)):
        raise CocdError(
            f"{folder} already holds a run ({existing_run(path)}): "
            "--resume continues it, --force replaces it"
        )
    # The table a run writes, in a folder without a run file: someone else's.
    if (folder / "stats.csv").exists() and not path.exists() and not force:
        raise CocdError(
            f"{folder} holds a stats.csv but no run file: a run would replace it; "
            "--force does, or give another --out"
        )
    writable_folder(folder, "--out")


def writable_folder(folder: Path, what: str) -> None:
    """Create ``folder`` (and its parents) or raise a one-line :class:`CocdError`."""
    import tempfile

    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".cocd-write-test-"):
            pass
    except FileExistsError:
        raise CocdError(f"{what} {folder}: a file is in the way of the folder") from None
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise CocdError(f"{what} {folder} cannot be written: {reason}") from None


def writable_file(path: Path, what: str, *, replace: bool = False) -> None:
    """Check, before any work, that ``path`` can be written (its folder is created) and,
    unless ``replace`` (the command's ``--force``), that no file is there already."""
    if path.is_dir():
        raise CocdError(f"{what} {path} is a folder, not a file")
    if path.exists() and not replace:
        raise CocdError(f"{what} {path} exists: --force replaces it")
    writable_folder(path.parent, what + " folder")
