"""The ``camcal`` command line."""

from __future__ import annotations

import typer

from camcal.cli import analyze, demo, fit, simulate, transport

app = typer.Typer(
    name="camcal",
    help="Camera-based optical calibration for deep-sea neutrino telescopes.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
simulate.register(app)
analyze.register(app)
demo.register(app)
fit.register(app)
transport.register(app)


def main() -> None:
    app()
