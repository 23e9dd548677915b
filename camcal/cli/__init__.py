"""The ``camcal`` command line."""

from __future__ import annotations

import typer

from camcal.cli import analyze, calibrate, data, demo, ingest, lrm, reanalyze, serve, simulate, simulate_lab

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
ingest.register(app)
lrm.register(app)
data.register(app)
serve.register(app)
simulate_lab.register(app)
calibrate.register(app)
reanalyze.register(app)


def main() -> None:
    app()
