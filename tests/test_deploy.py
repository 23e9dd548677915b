"""Configuration, the compose file and the Dockerfile: documented, valid, and true to the CLI."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from camcal.cli import app
from camcal.core.settings import Settings, field_names, load_settings
from tests.utils.system import free_ports

ROOT = Path(__file__).resolve().parents[1]
runner = CliRunner()


def test_every_setting_is_documented() -> None:
    doc = (ROOT / "docs" / "configuration.md").read_text()
    documented = set(re.findall(r"^\| `([a-z_.]+)` \|", doc, flags=re.M))
    names = set(field_names(Settings))
    missing = names - documented
    assert not missing, f"settings missing from docs/configuration.md: {sorted(missing)}"
    assert not documented - names, f"documented but not settings: {sorted(documented - names)}"


def test_environment_and_toml_feed_the_settings(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    toml = tmp_path / "camcal.toml"
    toml.write_text('data_dir = "/from/toml"\nhttp_port = 9000\n[alarms]\ntilt_major_deg = 9\n')
    monkeypatch.setenv("CAMCAL_CONFIG", str(toml))
    monkeypatch.setenv("CAMCAL_HTTP_PORT", "9100")
    monkeypatch.setenv("CAMCAL_ALARMS__TILT_MINOR_DEG", "4")
    monkeypatch.setenv("CAMCAL_OPERATOR_TOKENS", '{"alice": "secret-token-123"}')
    s = load_settings()
    assert str(s.data_dir) == "/from/toml" and s.http_port == 9100
    assert s.alarms.tilt_major_deg == 9 and s.alarms.tilt_minor_deg == 4
    assert s.tokens() == {"alice": "secret-token-123"}
    assert load_settings(http_port=9200).http_port == 9200
    # An empty variable (e.g. `CAMCAL_OPERATOR_TOKENS=` in a compose file) counts as unset.
    monkeypatch.setenv("CAMCAL_OPERATOR_TOKENS", "")
    monkeypatch.setenv("CAMCAL_HTTP_PORT", "")
    s = load_settings()
    assert s.tokens() == {} and s.http_port == 9000


def test_config_show_masks_secrets(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CAMCAL_OPERATOR_TOKENS", '{"alice": "secret-token-123"}')
    monkeypatch.setenv("CAMCAL_DATABASE_URL", "postgresql+psycopg://camcal:hunter22@db:5432/camcal")
    res = runner.invoke(app, ["config", "show"])
    assert res.exit_code == 0, res.output
    assert "secret-token-123" not in res.output and "hunter22" not in res.output
    assert '"alice": "********"' in res.output and "camcal:********@db:5432" in res.output


def test_a_bad_setting_is_one_line_naming_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CAMCAL_HTTP_PORT", "99999")
    proc = subprocess.run(
        [sys.executable, "-c", "from camcal.cli import main; main()", "config", "show"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2 and "http_port" in proc.stderr and "Traceback" not in proc.stderr


def compose() -> dict:
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


def test_compose_validates_against_the_compose_specification() -> None:
    exe = shutil.which("check-jsonschema") or str(Path(sys.executable).with_name("check-jsonschema"))
    proc = subprocess.run(
        [exe, "--builtin-schema", "vendor.compose-spec", str(ROOT / "docker-compose.yml")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr


def _commands() -> list[tuple[str, list[str]]]:
    out = []
    for name, svc in compose()["services"].items():
        if svc.get("image", "").startswith("camcal") or "build" in svc:
            out.append((name, svc["command"]))
            hc = svc.get("healthcheck", {}).get("test", [])
            if hc[:2] == ["CMD", "camcal"]:
                out.append((f"{name} healthcheck", hc[2:]))
    return out


@pytest.mark.parametrize(("service", "command"), _commands())
def test_compose_runs_real_camcal_commands_and_options(service: str, command: list[str]) -> None:
    words = [w for w in command if not w.startswith("-")]
    # the subcommand path: leading words until the first option
    path = []
    for w in command:
        if w.startswith("-"):
            break
        path.append(w)
    res = runner.invoke(app, [*path, "--help"])
    assert res.exit_code == 0, f"{service}: `camcal {' '.join(path)}` does not exist"
    helptext = re.sub(r"\s+", " ", res.output)
    for opt in (w for w in command if w.startswith("--")):
        assert opt in helptext, f"{service}: option {opt} is not in `camcal {' '.join(path)} --help`"
    assert words


def test_compose_environment_is_read_by_the_settings() -> None:
    fields = set(field_names(Settings))
    for name, svc in compose()["services"].items():
        for var in svc.get("environment") or {}:
            if var.startswith("CAMCAL_"):
                key = var[len("CAMCAL_") :].lower().replace("__", ".")
                assert key in fields, f"{name}: {var} is not a setting"


def test_dockerfile_copies_every_package_and_runs_camcal() -> None:
    text = (ROOT / "Dockerfile").read_text()
    copied = set(re.findall(r"^COPY (\w+) \./\w+$", text, flags=re.M))
    import tomllib

    packages = {
        p.rstrip("*")
        for p in tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"][
            "find"
        ]["include"]
    }
    assert packages <= copied, f"not copied into the image: {packages - copied}"
    assert 'ENTRYPOINT ["camcal"]' in text


def test_doctor_reports_what_to_fix(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CAMCAL_DATA_DIR", str(tmp_path / "nowhere"))
    monkeypatch.setenv("CAMCAL_HTTP_PORT", "1")
    # ports nothing listens on, whatever else runs on this machine (a `make run` on 5555, say)
    ingest_port, events_port = free_ports(2)
    monkeypatch.setenv("CAMCAL_INGEST_BIND", f"tcp://*:{ingest_port}")
    monkeypatch.setenv("CAMCAL_EVENTS_CONNECT", f"tcp://127.0.0.1:{events_port}")
    monkeypatch.setenv("COLUMNS", "300")  # one table row per line
    res = runner.invoke(app, ["doctor", "--wait", "0.2"])
    assert res.exit_code == 1
    # The console's width is fixed when it is made (COLUMNS above may come too late, as under
    # pytest-xdist): a detail cut over two lines reads as one once the table's rules are gone.
    out = re.sub(r"[\s│]+", " ", res.output)
    assert "does not exist" in out and "start `camcal ingest`" in out and "start `camcal serve`" in out
    (tmp_path / "nowhere").mkdir()
    res = runner.invoke(app, ["doctor", "--check", "data"])
    assert res.exit_code == 0 and "writable" in res.output
    assert json.loads(json.dumps(Settings().masked()))  # serialisable


def _unit(name: str = "camcal.service") -> dict[str, str]:
    text = (ROOT / "deploy" / name).read_text().replace("\\\n", " ")
    return {
        k.strip(): v.strip()
        for k, _, v in (line.partition("=") for line in text.splitlines())
        if v and not k.startswith(("#", "["))
    }


def test_systemd_unit_runs_a_real_camcal_command_and_uses_its_readiness() -> None:
    unit = _unit()
    words = unit["ExecStart"].split()
    assert words[0].endswith("/camcal") and words[1] == "up"
    res = runner.invoke(app, ["up", "--help"])
    helptext = re.sub(r"\s+", " ", res.output)
    for opt in (w for w in words if w.startswith("--")):
        assert opt in helptext, f"ExecStart: {opt} is not an option of `camcal up`"
    # camcal up notifies READY=1 once healthy and pings the watchdog; exit 2 is a configuration error
    assert unit["Type"] == "notify" and unit["NotifyAccess"] == "main" and "WatchdogSec" in unit
    from camcal.core import supervise

    assert unit["RestartPreventExitStatus"] == str(supervise.EXIT_USAGE)


def test_the_module_unit_runs_lrm_run_restarts_it_and_watches_it() -> None:
    unit = _unit("camcal-lrm.service")
    words = unit["ExecStart"].split()
    assert words[0].endswith("/camcal") and words[1:3] == ["lrm", "run"]
    res = runner.invoke(app, ["lrm", "run", "--help"], env={"COLUMNS": "300"})
    helptext = re.sub(r"\s+", " ", res.output)
    for opt in (w for w in words if w.startswith("--")):
        assert opt in helptext, f"ExecStart: {opt} is not an option of `camcal lrm run`"
    # the variables its comments tell a technician to set are the command's
    said = set(re.findall(r"#\s+(CAMCAL_\w+)=", (ROOT / "deploy" / "camcal-lrm.service").read_text()))
    assert said and all(f"env var: {v}" in helptext for v in said), said
    assert unit["Type"] == "notify" and unit["NotifyAccess"] == "main" and "WatchdogSec" in unit
    assert unit["Restart"] == "on-failure" and unit["StartLimitIntervalSec"] == "0"
    from camcal.core import supervise

    assert unit["RestartPreventExitStatus"] == str(supervise.EXIT_USAGE)


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed")
@pytest.mark.parametrize("name", ["camcal.service", "camcal-lrm.service"])
def test_systemd_accepts_the_unit(tmp_path: Path, name: str) -> None:
    """`systemd-analyze verify` on the unit, its camcal pointed at this installation's."""
    camcal = Path(sys.executable).with_name("camcal")
    text = (ROOT / "deploy" / name).read_text()
    text = text.replace("/opt/camcal/.venv/bin/camcal", str(camcal))
    (tmp_path / name).write_text(text)
    proc = subprocess.run(
        ["systemd-analyze", "verify", str(tmp_path / name)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0 and not proc.stderr.strip(), proc.stderr


def test_doctor_checks_the_module_link(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CAMCAL_DATA_DIR", str(tmp_path))
    ingest_port, events_port = free_ports(2)
    monkeypatch.setenv("CAMCAL_INGEST_BIND", f"tcp://*:{ingest_port}")
    monkeypatch.setenv("CAMCAL_EVENTS_CONNECT", f"tcp://127.0.0.1:{events_port}")
    monkeypatch.setenv("COLUMNS", "300")

    def link() -> str:
        res = runner.invoke(app, ["doctor", "--check", "ingest", "--wait", "0.1"])
        return re.sub(r"\s+", " ", res.output)

    assert "no ship key pair" in link() and "camcal keys create" in link()
    assert runner.invoke(app, ["keys", "create", "A", "B"]).exit_code == 0
    assert "CURVE; keys in" in link() and "modules let in: A, B" in link()
    monkeypatch.setenv("CAMCAL_LINK_PLAINTEXT", "true")
    assert "PLAINTEXT: no encryption" in link()


def test_doctor_says_when_a_modules_sd_card_could_not_keep_frames() -> None:
    from camcal.cli.doctor import OK, WARN, check_modules

    s = Settings()
    first = s.modules[0].id
    health = {
        "modules": {
            m.id: {"link": "up", "frames_per_s": 2.0, "clock_offset_s": 0.1, "card_skipped": 0}
            for m in s.modules
        }
    }
    health["modules"][first]["card_skipped"] = 7
    rows = check_modules(s, health)
    assert [r[1] for r in rows if r[0] == f"module {first}"] == [OK, WARN]
    assert "SD card could not keep 7" in next(r[2] for r in rows if r[1] == WARN)
    assert all(r[1] == OK for r in rows if r[0] != f"module {first}")


def test_operator_tokens_come_from_a_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    as_json = tmp_path / "tokens.json"
    as_json.write_text('{"alice": "secret-token-123"}')
    monkeypatch.setenv("CAMCAL_OPERATOR_TOKENS_FILE", str(as_json))
    assert Settings().tokens() == {"alice": "secret-token-123"}
    as_lines = tmp_path / "tokens"
    as_lines.write_text("# operators\nalice = secret-token-123\nbob=another-token-456\n")
    monkeypatch.setenv("CAMCAL_OPERATOR_TOKENS_FILE", str(as_lines))
    assert Settings().tokens() == {"alice": "secret-token-123", "bob": "another-token-456"}
    assert "secret-token" not in json.dumps(Settings().masked())
    as_lines.write_text("alice secret-token-123\n")
    with pytest.raises(ValueError, match="line 1: expected NAME=TOKEN"):
        Settings().tokens()


def test_the_image_installs_the_extras_its_services_need() -> None:
    """The compose file runs the ship (ingest, serve, doctor) on PostgreSQL: the image needs `ship`
    and `postgres`; a module needs no extra, so the simulated modules run on the same image."""
    import tomllib

    text = (ROOT / "Dockerfile").read_text()
    (spec,) = re.findall(r"pip install '\.\[([a-z,]+)\]'", text)
    extras = set(spec.split(","))
    declared = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"])
    assert extras <= declared, f"not extras of pyproject.toml: {extras - declared}"
    services = compose()["services"]
    assert services["ingest"]["environment"]["CAMCAL_DATABASE_URL"].startswith("postgresql+psycopg://")
    assert {"ship", "postgres"} <= extras
