"""``camcal demo``: simulate a dive's frame set, analyse it, compare with the truth."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table
from rich.text import Text

from camcal.cli.analyze import print_summary
from camcal.cli.common import console, fail, progress_bar, yes_no


def register(app: typer.Typer) -> None:
    app.command("demo")(demo)


def demo(
    out: Annotated[Path, typer.Option(help="Folder for the frame set, plots and result.")] = Path(
        "demo-output"
    ),
    water: Annotated[str, typer.Option(help="Water preset: trex, clear, turbid.")] = "trex",
    seed: Annotated[int, typer.Option(help="Simulation seed.")] = 1,
    repeats: Annotated[int, typer.Option(help="Frames per setting.")] = 3,
) -> None:
    """Simulate a T-REX frame set at 3420 m, analyse it and compare λ_att with the truth."""
    from camcal.core.files import write_atomic
    from camcal.core.schedule import Schedule
    from camcal.pipeline import analyze_folder, to_json
    from camcal.plots import write_plots
    from lrm.sim.scene import water_preset
    from lrm.simset import SimulationSpec, simulate_frame_set

    try:
        w = water_preset(water)
    except ValueError as exc:
        raise fail(str(exc)) from None
    frameset = out / "frameset"
    if frameset.exists():
        shutil.rmtree(frameset)
    schedule = Schedule(
        name="demo",
        exposures_s=(0.02, 0.05, 0.07, 0.11, 0.2),
        gains_db=(2.0, 6.0, 10.0, 14.0),
        repeats=repeats,
    )
    spec = SimulationSpec(water=w, schedule=schedule, seed=seed)
    console.rule(Text("1. simulate", style="bold"))
    console.print(
        f"{schedule.n_frames * 2} frames of 2448 x 2048 px, {w.name} water, "
        f"cameras A at 21.56 m and B at 41.62 m"
    )
    with progress_bar("rendering") as update:
        truth = simulate_frame_set(frameset, spec, progress=update)
    console.rule(Text("2. analyse", style="bold"))
    with progress_bar("analysing") as update:
        an = analyze_folder(frameset, progress=update)
    print_summary(an)
    write_atomic(out / "result.json", (json.dumps(to_json(an), indent=1) + "\n").encode(), fsync=False)
    plots = write_plots(an, out / "plots")
    console.rule(Text("3. against the simulated truth", style="bold"))
    table = Table()
    for col in ("wavelength", "true λ_att [m]", "measured [m]", "deviation", "pull (stat⊕sys)", "within 3 %"):
        table.add_column(col, justify="right")
    all_ok = True
    water_truth = truth["water"]
    assert isinstance(water_truth, dict)
    for wl_s, o in sorted(water_truth.items()):
        true = o["lambda_att_m"]
        res = an.result.attenuation.get(int(wl_s)) if an.result else None
        if res is None or res.lambda_att_m is None:
            table.add_row(f"{wl_s} nm", f"{true:.2f}", "—", "—", "—", yes_no(False))
            all_ok = False
            continue
        dev = (res.lambda_att_m - true) / true
        pull = (res.lambda_att_m - true) / (res.total_err_m or float("inf"))
        ok = abs(dev) <= 0.03
        all_ok &= ok
        table.add_row(
            f"{wl_s} nm",
            f"{true:.2f}",
            f"{res.lambda_att_m:.2f}",
            f"{100 * dev:+.1f} %",
            f"{pull:+.2f}",
            yes_no(ok),
        )
    console.print(table)
    console.print(f"frame set: {frameset}\nresult:    {out / 'result.json'}")
    for p in plots:
        console.print(f"plot:      {p}")
    if not all_ok:
        raise fail("a wavelength missed the truth by more than 3 %", code=1)
