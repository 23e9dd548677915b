"""Shared pieces of the command line: errors, progress, consoles, the options every store command takes."""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.text import Text

from camcal.cli.defaults import DATA_DIR

if TYPE_CHECKING:
    from rich.progress import Progress

# Plain text unless styled on purpose: a path, a key or an error message holding "[b]" is
# printed as it is, never read as rich markup (which once dropped it from a listed key). Style
# goes in as rich Text: `labelled("warning:", "yellow", message)` or `Text(word, style=...)`.
console = Console(markup=False)
err_console = Console(stderr=True, markup=False)


def labelled(label: str, style: str, rest: str = "") -> Text:
    """``label`` in ``style``, then a space and ``rest`` as plain text."""
    return Text.assemble((label, style), f" {rest}" if rest else "")


def yes_no(ok: bool) -> Text:
    """A table cell: "yes" in green or "no" in red."""
    return Text("yes", style="green") if ok else Text("no", style="red")


# Where the store is: one declaration for every command that opens it. Unset, both come
# from the typed settings (`camcal.core.settings`): CAMCAL_DATA_DIR, CAMCAL_DATABASE_URL,
# the TOML file CAMCAL_CONFIG names, then the default (camcal-data, SQLite in it).
DataOption = Annotated[
    Path | None,
    typer.Option(
        "--data",
        help=f"Data folder of the store (else CAMCAL_DATA_DIR, the config file's data_dir, {DATA_DIR}).",
        show_default=False,
    ),
]
DbUrlOption = Annotated[
    str | None,
    typer.Option(
        "--db-url",
        help="SQLAlchemy URL of the store (else CAMCAL_DATABASE_URL, the config file's database_url, "
        "SQLite in the data folder).",
        show_default=False,
    ),
]


def writable_output(path: Path | None, option: str, *, folder: bool = False) -> None:
    """Refuse (one line, exit 2) an output path the command could not write, before any work.

    ``folder``: the option names a folder to create (``--plots``), else a file (``--json``). The
    folder that will hold the output is created and a file tried in it, as the command would.
    """
    if path is None:
        return
    if not folder and (str(path) == "." or path.is_dir()):
        raise fail(f"{option} {str(path)!r}: a folder, not a file: name a file, e.g. {path / 'result.json'}")
    if folder and path.exists() and not path.is_dir():
        raise fail(f"{option} {path}: a file, not a folder: choose a folder for the figures")
    target = path if folder else path.parent
    try:
        target.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=target):
            pass
    except OSError as exc:
        raise fail(
            f"{option} {path}: cannot write in {target} ({exc.strerror or exc}): choose another path"
        ) from None


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print one line to stderr and return the exit to raise (no traceback)."""
    err_console.print(labelled("error:", "bold red", message), highlight=False, soft_wrap=True)
    return typer.Exit(code)


def progress(*, transient: bool) -> Progress:
    """A rich progress display on stderr: what, a bar, done of total, the time left."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    return Progress(
        TextColumn("{task.description}", style="bold", markup=False),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=err_console,
        transient=transient,
    )


@contextmanager
def progress_bar(label: str, *, quiet: bool = False) -> Iterator[Callable[[int, int], None]]:
    """A progress bar on stderr; yields ``update(done, total)``."""
    if quiet:
        yield lambda done, total: None
        return
    with progress(transient=False) as prog:
        task = prog.add_task(label, total=None)

        def update(done: int, total: int) -> None:
            prog.update(task, completed=done, total=total)

        yield update


def parse_floats(text: str, what: str) -> tuple[float, ...]:
    """``"0.02,0.05"`` -> ``(0.02, 0.05)``; a bad item names the option."""
    try:
        values = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise fail(f"{what}: {text!r} is not a comma-separated list of numbers") from None
    if not values:
        raise fail(f"{what}: empty list")
    return values


def parse_mapping(items: list[str] | str | None, what: str) -> dict[str, float]:
    """``["A=21.5", "B=41.6"]`` or ``"405=39,460=65"`` -> ``{"A": 21.5, ...}``."""
    if not items:
        return {}
    if isinstance(items, str):
        items = [x for x in items.split(",") if x.strip()]
    out: dict[str, float] = {}
    for item in items:
        for part in item.split(","):
            if not part.strip():
                continue
            key, sep, value = part.partition("=")
            if not sep or not key.strip():
                raise fail(f"{what}: expected KEY=VALUE, got {part!r}")
            try:
                out[key.strip()] = float(value)
            except ValueError:
                raise fail(f"{what}: {value!r} is not a number (in {part!r})") from None
    return out
