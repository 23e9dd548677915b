"""The ``camcal`` command line.

Starting it is cheap: ``camcal --help`` imports no command at all (the list
below holds each one's name, module and one-line help), ``camcal COMMAND``
imports and builds that command alone, and each command's module declares
its options with plain defaults (`camcal.cli.defaults`) and imports what its
work needs when it runs. No SciPy, OpenCV, database or web framework is
loaded to parse a command line or print help; ``tests/cli/test_startup.py``
checks that, and that this list matches the commands.

``camcal.cli.app`` is the whole Typer application with every command
registered (what tests invoke); ``main`` is the ``camcal`` entry point.
"""

from __future__ import annotations

import importlib
import importlib.machinery
import os
import re
import sys
import types
from typing import Any

import typer
from typer.core import TyperCommand, TyperGroup
from typer.models import DefaultPlaceholder

HELP = "Camera-based optical calibration for deep-sea neutrino telescopes."

#: Every command in the order ``camcal --help`` lists them: name, module of `camcal.cli`, one-line help.
COMMANDS: tuple[tuple[str, str, str], ...] = (
    # The science: simulate, analyse, fit.
    (
        "simulate-set",
        "simulate",
        "Simulate a dive's frame set (manifest, setup.json, PNGs) and its ground truth (truth.json).",
    ),
    ("analyze", "analyze", "Measure I_center on every frame and the attenuation length per wavelength."),
    ("demo", "demo", "Simulate a T-REX frame set at 3420 m, analyse it and compare λ_att with the truth."),
    ("fit", "fit", "Fit absorption and scattering lengths to both cameras' radial profiles, per wavelength."),
    (
        "report",
        "report",
        "Write a dive's report as ONE self-contained HTML file that opens offline (a USB stick, e-mail).",
    ),
    # The live system.
    (
        "ingest",
        "ingest",
        "Receive frames and sensor packets from the modules, store, analyse and publish them.",
    ),
    ("serve", "serve", "Serve the dashboard and the API (OpenAPI at /docs) for a data folder."),
    (
        "up",
        "up",
        "Start the whole system: ingest, two simulated modules on a simulated dive, and the dashboard.",
    ),
    (
        "import",
        "data",
        "Load an SD-card frame set into a dive: frames already stored are skipped, gaps are filled.",
    ),
    (
        "export",
        "data",
        "Write a dive's tables (frames with results, sensors, attitude, λ_att, alarms...) to CSV and "
        "Parquet.",
    ),
    # Calibrations and operations.
    (
        "simulate-lab",
        "simulate_lab",
        "Simulate a lab calibration: linearity, emission-ratio, air-scan, tank-scan or psf (+ truth.json).",
    ),
    (
        "doctor",
        "doctor",
        "Check the configuration, data folder, disk, database, ingest, modules, dashboard, and list "
        "camcal's processes (with the ports they hold; those left behind by a camcal that ended are a "
        "warning).",
    ),
    (
        "reanalyze",
        "reanalyze",
        "Re-analyse a stored dive, a time span, or frame-set folders with another calibration, on Dask.",
    ),
    # Groups of subcommands.
    (
        "transport",
        "transport",
        "Photon transport: the refined model's c1/c2 coefficients, the template cache.",
    ),
    ("keys", "keys", "The module link's keys (ZeroMQ CURVE): one pair for the ship, one per module."),
    ("lrm", "lrm", "Run a light receiver module: a real camera, simulated, or replaying a frame set."),
    (
        "calibrate",
        "calibrate",
        "Lab calibrations of the camera system: one subcommand per experiment, each on a frame set.",
    ),
    ("dive", "dive", "The dives in the store: list them, end one."),
    ("calibration", "calibration", "Versioned calibration records: add, list, show."),
    ("config", "config", "The configuration: CAMCAL_ environment variables and an optional TOML file."),
)
#: `camcal.core.supervise.CHANNEL_ENV`: set when a supervisor (``camcal up``) started this command.
SUPERVISOR_ENV = "CAMCAL_SUPERVISOR_FD"
_MODULE_OF = {name: module for name, module, _ in COMMANDS}
_HELP_OF = {name: text for name, _, text in COMMANDS}


def _typer(**kwargs: Any) -> typer.Typer:
    return typer.Typer(add_completion=False, pretty_exceptions_enable=False, **kwargs)


def _register(target: typer.Typer, module: str) -> None:
    importlib.import_module(f"camcal.cli.{module}").register(target)
    for group in target.registered_groups:  # ``lrm``, ``calibrate`` ...: groups of subcommands
        if isinstance(group.cls, DefaultPlaceholder):
            group.cls = _Group
        for sub in group.typer_instance.registered_commands if group.typer_instance else ():
            sub.cls = _Command if sub.cls in (None, TyperCommand) else sub.cls
    for command in target.registered_commands:
        command.cls = _Command if command.cls in (None, TyperCommand) else command.cls


def build_app() -> typer.Typer:
    """The whole application, every command registered (their modules imported)."""
    full = _typer(name="camcal", help=HELP, no_args_is_help=True, cls=_Group)
    for module in dict.fromkeys(_MODULE_OF.values()):  # each module once, in the listed order
        _register(full, module)
    return full


def _plain_help_flag(option: Any) -> Any:
    """``option`` (a ``--help`` flag) taking "not given" as it is, without typer's pydantic adapter.

    A group parses its own options before its subcommand's: its ``--help``,
    not given, goes through typer's coercion, whose first use imports pydantic
    and looks up pydantic's plugins (~0.1 s of ``camcal lrm --help``) to turn
    "absent" into None. A flag is True, False or absent; nothing to coerce.
    With a typer whose internals differ, the option is left as it is (slower, same result).
    """
    try:
        from typer._coercion import PassThroughRuntimeParam

        if option is not None and option._runtime_param is None:
            option._runtime_param = PassThroughRuntimeParam(
                parameter_info=option.type_descriptor.parameter_info, annotation=bool
            )
    except (ImportError, AttributeError, TypeError):
        pass
    return option


#: What rich takes for a markup tag (``rich.markup``): "[m]" or "[px]", a unit in a help text, is one.
_TAG = re.compile(r"(\\*)(\[[a-z#/@][^[]*?])")


def _as_written(text: str | None) -> str | None:
    """``text`` escaped for rich's markup, so that typer's help shows it as written."""
    return None if text is None else _TAG.sub(lambda m: m.group(1) * 2 + "\\" + m.group(2), text)


class _Command(TyperCommand):
    """A command whose help shows units as written: "depth [m]", not "depth" (rich ate "[m]")."""

    def format_help(self, ctx: Any, formatter: Any) -> None:
        if self.rich_markup_mode == "rich" and not getattr(self, "_escaped", False):
            self.help = _as_written(self.help)
            for param in self.params:
                if isinstance(getattr(param, "help", None), str):
                    param.help = _as_written(param.help)  # type: ignore[attr-defined]
            self._escaped = True
        super().format_help(ctx, formatter)


class _Group(TyperGroup):
    """A group of commands (``camcal``, ``camcal lrm`` ...) whose ``--help`` flag costs no pydantic."""

    def get_help_option(self, ctx: Any) -> Any:
        return _plain_help_flag(super().get_help_option(ctx))


class _LazyGroup(_Group):
    """The root group of ``camcal``: lists every command, builds only the one it runs."""

    def list_commands(self, ctx: Any) -> list[str]:
        return [name for name, _, _ in COMMANDS]

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        if cmd_name in self.commands:
            return self.commands[cmd_name]
        if cmd_name in _HELP_OF:  # listed in the root's help: its one line is all that is needed
            return TyperCommand(cmd_name, help=_HELP_OF[cmd_name])
        return None

    def resolve_command(self, ctx: Any, args: list[str]) -> Any:
        name = args[0] if args else None
        if name in _MODULE_OF and name not in self.commands:
            one = _typer()
            _register(one, _MODULE_OF[name])
            self.commands.update(typer.main.get_group(one).commands)
        return super().resolve_command(ctx, args)


_root = _typer(name="camcal", help=HELP, no_args_is_help=True, cls=_LazyGroup)


@_root.callback()
def _root_options() -> None:
    pass


def __getattr__(name: str) -> Any:
    if name == "app":  # built on first use: importing `camcal.cli` imports no command
        globals()["app"] = built = build_app()
        return built
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class _Deferred(type):
    """A stand-in for a class of a module not imported yet: using it imports the module."""

    def _real(cls) -> Any:
        return getattr(importlib.import_module(cls.__module__), cls.__name__)

    def __call__(cls, *args: Any, **kwargs: Any) -> Any:
        return cls._real()(*args, **kwargs)

    def __getattr__(cls, name: str) -> Any:
        return getattr(cls._real(), name)


#: What typer's help renderer imports but uses only for Markdown help text and pretty
#: tracebacks (neither of which camcal uses): ~0.1 s of every ``--help``.
_RENDERER_EXTRAS = (("rich.markdown", "Markdown"), ("rich.traceback", "Traceback"))


def _import_help_renderer() -> None:
    """Import ``typer.rich_utils`` with stand-ins for rich's Markdown and Traceback.

    The stand-ins leave `sys.modules` once the renderer is imported: any later
    ``import rich.markdown`` gets the real module, and the renderer's names
    import it if they are ever used.
    """
    if "typer.rich_utils" in sys.modules:
        return
    placed = {}
    for module, name in _RENDERER_EXTRAS:
        if module not in sys.modules:
            stand_in = types.ModuleType(module)
            setattr(stand_in, name, _Deferred(name, (), {"__module__": module}))
            placed[module] = sys.modules[module] = stand_in
    try:
        import typer.rich_utils  # noqa: F401
    except ImportError:  # no rich: typer prints plain help
        pass
    finally:
        for module, stand_in in placed.items():
            if sys.modules.get(module) is stand_in:
                del sys.modules[module]


def main() -> None:
    if SUPERVISOR_ENV in os.environ:  # (importing `supervise` costs ~20 ms: only when it has work)
        from camcal.core import supervise

        supervise.attach()  # started by `camcal up`: end with it, however it ends
    if "--help" in sys.argv[1:]:
        _import_help_renderer()
    _workers_skip_the_entry_script()
    try:
        _root()
    except ImportError as exc:
        from camcal.cli.extras import missing_extra

        message = missing_extra(exc)
        if message is None:
            raise
        from camcal.cli.common import err_console, labelled

        err_console.print(labelled("error:", "bold red", message), highlight=False, soft_wrap=True)
        raise SystemExit(2) from None
    except OSError as exc:  # a full or read-only disk under any command: one line, not a traceback
        message = disk_trouble(exc)
        if message is None:
            raise
        from camcal.cli.common import err_console, labelled

        err_console.print(labelled("error:", "bold red", message), highlight=False, soft_wrap=True)
        raise SystemExit(1) from None


def disk_trouble(exc: OSError) -> str | None:
    """The one line for a write the disk refused (full, over quota, read-only, not permitted), or
    None for any other OSError (those keep their traceback: they are not the disk's)."""
    import errno

    advice = {
        errno.ENOSPC: "no space left: free space or write elsewhere",
        errno.EDQUOT: "over the disk quota: free space or write elsewhere",
        errno.EROFS: "the file system is read-only: remount it read-write or write elsewhere",
        errno.EACCES: "permission denied: write elsewhere or fix the folder's permissions",
    }.get(exc.errno or -1)
    if advice is None:
        return None
    where = f" to {exc.filename}" if exc.filename else ""
    return f"a write{where} failed, {advice}"


def _workers_skip_the_entry_script() -> None:
    """Worker processes (analysis pools) start by re-running the parent's ``__main__``,
    which for the ``camcal`` script means importing every command (~0.5 s each,
    for nothing: they only run functions of importable modules). A main module
    named like a package's ``__main__`` is one multiprocessing never re-runs, as
    for ``python -m camcal``."""
    entry = sys.modules.get("__main__")
    if entry is not None and getattr(entry, "__spec__", None) is None:
        entry.__spec__ = importlib.machinery.ModuleSpec("camcal.__main__", None)
