"""The ``camcal`` command line."""

from __future__ import annotations

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
    lrm,
    reanalyze,
    report,
    serve,
    simulate,
    simulate_lab,
    transport,
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
lrm.register(app)
serve.register(app)
data.register(app)
# Calibrations and operations.
simulate_lab.register(app)
calibrate.register(app)
calibration.register(app)
config.register(app)
doctor.register(app)
reanalyze.register(app)


def main() -> None:
    app()
