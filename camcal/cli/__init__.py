"""The ``camcal`` command line.

Importing it is cheap (``camcal --help`` in well under a second, no SciPy,
OpenCV, database or web framework loaded): each command's module declares
its options with plain defaults (`camcal.cli.defaults`) and imports what
its work needs when it runs. ``tests/cli/test_startup.py`` checks it.
"""

from __future__ import annotations

import importlib.machinery
import sys

import typer

from camcal.cli import (
    analyze,
    calibrate,
    calibration,
    config,
    data,
    demo,
    doctor,
    fit,
    ingest,
    keys,
    lrm,
    reanalyze,
    report,
    serve,
    simulate,
    simulate_lab,
    transport,
    up,
)

app = typer.Typer(
    name="camcal",
    help="Camera-based optical calibration for deep-sea neutrino telescopes.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
# The science: simulate, analyse, fit.
simulate.register(app)
analyze.register(app)
demo.register(app)
fit.register(app)
transport.register(app)
report.register(app)
# The live system.
ingest.register(app)
keys.register(app)
lrm.register(app)
serve.register(app)
up.register(app)
data.register(app)
# Calibrations and operations.
simulate_lab.register(app)
calibrate.register(app)
calibration.register(app)
config.register(app)
doctor.register(app)
reanalyze.register(app)


def main() -> None:
    from camcal.core import supervise

    supervise.attach()  # started by `camcal up`: end with it, however it ends
    _workers_skip_the_entry_script()
    try:
        app()
    except ImportError as exc:
        from camcal.cli.extras import missing_extra

        message = missing_extra(exc)
        if message is None:
            raise
        from rich.markup import escape

        from camcal.cli.common import err_console

        err_console.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)
        raise SystemExit(2) from None


def _workers_skip_the_entry_script() -> None:
    """Worker processes (analysis pools) start by re-running the parent's ``__main__``,
    which for the ``camcal`` script means importing every command (~0.5 s each,
    for nothing: they only run functions of importable modules). A main module
    named like a package's ``__main__`` is one multiprocessing never re-runs, as
    for ``python -m camcal``."""
    entry = sys.modules.get("__main__")
    if entry is not None and getattr(entry, "__spec__", None) is None:
        entry.__spec__ = importlib.machinery.ModuleSpec("camcal.__main__", None)
