"""``camcal config show``: the effective configuration, secrets masked."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from camcal.cli.common import console, fail

if TYPE_CHECKING:
    from camcal.core.settings import Settings

app = typer.Typer(
    help="The configuration: CAMCAL_ environment variables and an optional TOML file.", no_args_is_help=True
)


def register(parent: typer.Typer) -> None:
    parent.add_typer(app, name="config")


def settings_or_fail(config: Path | None = None, **overrides: object) -> Settings:
    """Load the settings; a bad value is one line naming the setting and what is wrong."""
    from pydantic import ValidationError

    from camcal.core.settings import load_settings

    try:
        return load_settings(config, **overrides)
    except ValidationError as exc:
        e = exc.errors()[0]
        where = ".".join(str(p) for p in e["loc"])
        raise fail(f"configuration: {where}: {e['msg']} (see docs/configuration.md)") from None
    except (OSError, ValueError) as exc:
        raise fail(f"configuration: {exc}") from None


@app.command("show")
def show(config: Annotated[Path | None, typer.Option(help="A TOML configuration file.")] = None) -> None:
    """Print the effective configuration as JSON, with tokens and passwords masked."""
    settings = settings_or_fail(config)
    console.print_json(json.dumps(settings.masked()))
