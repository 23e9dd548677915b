"""The command line starts light, and a command whose extra is missing says which one to install.

Each check runs a fresh interpreter (``sys.modules`` of this test process
holds everything by now) and reports which heavy modules it loaded. Timing
lives in ``bench/bench_startup.py``, not here.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

#: Never needed to parse a command line or print help.
HEAVY = (
    "scipy",
    "cv2",
    "numpy",
    "zmq",
    "pydantic_settings",
    "fastapi",
    "starlette",
    "uvicorn",
    "sqlalchemy",
    "alembic",
    "matplotlib",
    "pyarrow",
    "dask",
    "distributed",
    "fsspec",
    "analysis",
    "lrm",
    "ingest",
    "storage",
    "server",
    "camcal.core.frameset",
    "camcal.core.settings",
    "pydantic",  # typer coerces an absent --help flag with it unless told not to (`camcal.cli._Group`)
)
#: What ``camcal --help`` and ``camcal lrm --help`` (through the entry point) do without, beyond HEAVY:
#: rich's Markdown and tracebacks (imported by typer's help renderer, never used by camcal's help) and
#: the supervisor's channel (only when ``camcal up`` started the command).
RENDERER_EXTRAS = ("rich.markdown", "markdown_it", "rich.traceback", "rich.pretty", "camcal.core.supervise")

_PROBE = """
import contextlib, io, json, sys
heavy = json.loads(sys.argv[1])
from camcal.cli import main
sys.argv = ["camcal", *sys.argv[2:]]
code = 0
with contextlib.redirect_stdout(io.StringIO()):
    try:
        main()
    except SystemExit as exc:
        code = exc.code or 0
print(json.dumps({"code": code, "loaded": [m for m in heavy if m in sys.modules]}))
"""


def loaded_by(*args: str, heavy: tuple[str, ...] = HEAVY) -> dict[str, object]:
    """Run the CLI with ``args`` in a fresh interpreter: its exit status and the heavy modules it loaded."""
    out = subprocess.run(
        [sys.executable, "-c", _PROBE, json.dumps(heavy), *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.splitlines()[-1])


def test_importing_the_cli_loads_no_heavy_module() -> None:
    probe = "import json, sys; import camcal.cli; print(json.dumps([m for m in json.loads(sys.argv[1]) if m in sys.modules]))"  # noqa: E501
    out = subprocess.run(
        [sys.executable, "-c", probe, json.dumps(HEAVY)], cwd=ROOT, capture_output=True, text=True, check=True
    )
    assert json.loads(out.stdout) == []


@pytest.mark.parametrize("args", [["--help"], ["lrm", "--help"]])
def test_help_loads_no_heavy_module(args: list[str]) -> None:
    got = loaded_by(*args, heavy=(*HEAVY, *RENDERER_EXTRAS))
    assert got == {"code": 0, "loaded": []}


def test_the_help_renderer_stand_ins_leave_no_trace() -> None:
    """After ``--help`` the real rich.markdown and rich.traceback import, and typer's renderer uses them."""
    probe = (
        "import contextlib, io, sys\n"
        "from camcal.cli import main\n"
        "sys.argv = ['camcal', 'lrm', '--help']\n"
        "with contextlib.redirect_stdout(io.StringIO()) as out, contextlib.suppress(SystemExit):\n"
        "    main()\n"
        "assert 'replay' in out.getvalue()\n"
        "import rich.markdown, rich.traceback, typer.rich_utils as r\n"
        "assert isinstance(r.Markdown('*x*'), rich.markdown.Markdown)\n"
        "assert r.Traceback.from_exception is not None\n"
        "assert rich.markdown.Markdown.__init__ is not type.__init__\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, check=False)
    assert out.stdout.strip() == "ok", out.stderr


def test_the_supervisor_variable_is_the_supervisors() -> None:
    from camcal.cli import SUPERVISOR_ENV
    from camcal.core.supervise import CHANNEL_ENV

    assert SUPERVISOR_ENV == CHANNEL_ENV


def test_every_commands_help_stays_light() -> None:
    """``camcal COMMAND --help`` for every command and subcommand: options declared with plain defaults."""
    from typer.main import get_command

    from camcal.cli import app

    root = get_command(app)
    paths: list[list[str]] = []
    for name, cmd in root.commands.items():  # type: ignore[attr-defined]
        subs = getattr(cmd, "commands", None)
        paths += [[name, sub] for sub in subs] if subs else [[name]]
    assert len(paths) >= 20
    script = (
        "import contextlib, io, json, sys\n"
        "from camcal.cli import app\n"
        "heavy, paths = json.loads(sys.argv[1]), json.loads(sys.argv[2])\n"
        "out = {}\n"
        "for p in paths:\n"
        "    with contextlib.redirect_stdout(io.StringIO()):\n"
        "        try:\n"
        "            app([*p, '--help'])\n"
        "        except SystemExit:\n"
        "            pass\n"
        "    out[' '.join(p)] = [m for m in heavy if m in sys.modules]\n"
        "print(json.dumps(out))\n"
    )
    res = subprocess.run(
        [sys.executable, "-c", script, json.dumps(HEAVY), json.dumps(paths)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    loaded = json.loads(res.stdout.splitlines()[-1])
    assert set(loaded) == {" ".join(p) for p in paths}
    assert {cmd: mods for cmd, mods in loaded.items() if mods} == {}


def test_defaults_are_the_values_of_their_owners() -> None:
    """The plain constants of `camcal.cli.defaults` equal what the modules that own them compute."""
    pytest.importorskip("pydantic_settings")  # the ship's (`Settings`); the rest is core
    from analysis.calibration import DEEP_SEA_TEMPERATURE_C
    from camcal.calibrate.scans import LEM_DIAMETER_M
    from camcal.cli import defaults
    from camcal.core.settings import Settings
    from lrm.labset import LAB_KINDS
    from lrm.sim.camera import CameraModel

    assert CameraModel().focal_px == pytest.approx(defaults.TREX_FOCAL_PX, rel=1e-12)
    assert defaults.DEEP_SEA_TEMPERATURE_C == DEEP_SEA_TEMPERATURE_C
    assert defaults.LEM_DIAMETER_M == LEM_DIAMETER_M
    assert tuple(defaults.LAB_KINDS) == tuple(LAB_KINDS)
    assert Path(defaults.DATA_DIR) == Settings.model_fields["data_dir"].default


def test_the_fork_server_preloads_no_scipy() -> None:
    """Workers analyse frames (numpy, OpenCV, `analysis`): a fork server importing SciPy only costs."""
    from camcal.core import parallel

    assert not any(m.split(".")[0] == "scipy" for m in parallel._PRELOAD)
    probe = (
        "import sys, json; [__import__(m) for m in json.loads(sys.argv[1])]; print('scipy' in sys.modules)"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe, json.dumps(parallel._PRELOAD)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    )
    assert out.stdout.strip() == "False"


# -- a missing extra ------------------------------------------------------------------------------

_BLOCKED = """
import sys
blocked = set(sys.argv[1].split(","))

class Blocker:
    '''An install without these distributions: importing them fails as it would there.'''

    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in blocked:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, Blocker())
from camcal.cli import main
sys.argv = ["camcal", *sys.argv[2:]]
main()
"""


def without(modules: str, *args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", _BLOCKED, modules, *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env={**_clean_env(), "PYTHONPATH": str(ROOT), "COLUMNS": "200"},
    )


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _clean_env() -> dict[str, str]:
    import os

    return {k: v for k, v in os.environ.items() if not k.startswith("CAMCAL_")}


@pytest.mark.parametrize(
    ("blocked", "args", "extra", "needs"),
    [
        ("sqlalchemy", ["calibration", "list", "--data", "{tmp}"], "ship", ["pydantic_settings"]),
        ("pydantic_settings", ["config", "show"], "ship", []),
        ("fastapi", ["serve", "--data", "{tmp}", "--port", "{port}"], "ship", ["pydantic_settings"]),
        (
            "matplotlib",
            ["analyze", "{set}", "--plots", "{tmp}/plots", "--quiet", "--workers", "1"],
            "plots",
            [],
        ),
        (
            "psycopg",
            ["export", "--db-url", "postgresql+psycopg://u:p@127.0.0.1:1/x"],
            "postgres",
            ["pydantic_settings", "sqlalchemy"],
        ),
    ],
)
def test_a_missing_extra_is_one_line_naming_it(
    blocked: str, args: list[str], extra: str, needs: list[str], tmp_path: Path, trex_small_set: Path
) -> None:
    for other in needs:  # a module-only install lacks these too: the command would name them first
        pytest.importorskip(other)
    argv = [a.format(tmp=tmp_path, set=trex_small_set, port=free_port()) for a in args]
    out = without(blocked, *argv, cwd=tmp_path)
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, out.stderr
    assert f"camcal[{extra}]" in lines[0] and repr(blocked) in lines[0]


def test_without_any_extra_the_module_side_runs(tmp_path: Path) -> None:
    """Every extra blocked at once: the module's commands still parse, and an unrelated error is not
    dressed up as a missing extra."""
    from camcal.cli.extras import EXTRA_OF_MODULE

    everything = ",".join(EXTRA_OF_MODULE)
    out = without(everything, "lrm", "--help", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "simulate" in out.stdout and "replay" in out.stdout
    out = without(everything, "lrm", "replay", str(tmp_path / "nothing"), "--camera", "A", cwd=tmp_path)
    assert out.returncode == 2 and "camcal[" not in out.stderr and "Traceback" not in out.stderr


def test_the_root_list_is_the_commands() -> None:
    """``camcal --help`` prints `camcal.cli.COMMANDS` without importing a command: the same names, in
    the same order, with each command's own one-line help, as the application with every command."""
    from typer.main import get_command

    from camcal.cli import COMMANDS, app

    full = get_command(app)
    listed = full.list_commands(None)  # type: ignore[attr-defined]
    assert [name for name, _, _ in COMMANDS] == listed
    for name, module, text in COMMANDS:
        cmd = full.get_command(None, name)  # type: ignore[attr-defined]
        assert cmd.get_short_help_str(limit=1000) == text, name
        owner = cmd.callback.__module__ if cmd.callback else None
        subs = getattr(cmd, "commands", {})
        owners = {owner} if owner else {c.callback.__module__ for c in subs.values()}
        # (a group's subcommands may live beside its module, `lrm_camera` beside `lrm`: it imports them)
        assert f"camcal.cli.{module}" in owners or not subs, name
        assert all(o == f"camcal.cli.{module}" or o.startswith(f"camcal.cli.{module}_") for o in owners), name


def test_the_entry_point_runs_the_commands_it_lists(tmp_path: Path) -> None:
    """Through ``main`` (what the ``camcal`` script runs): a listed command, a subcommand, an unknown
    one."""
    got = loaded_by("lrm", "simulate", "--help")
    assert got["code"] == 0
    out = subprocess.run(
        [sys.executable, "-c", "from camcal.cli import main; main()", "calibration", "nope"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert out.returncode == 2 and "No such command 'nope'" in out.stderr
    out = subprocess.run(
        [sys.executable, "-c", "from camcal.cli import main; main()", "simulate-lab", "psf",
         str(tmp_path / "s"), "--width", "128", "--height", "128", "--repeats", "1", "--quiet"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "s" / "manifest.csv").is_file()
