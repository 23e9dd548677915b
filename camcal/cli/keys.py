"""``camcal keys``: the module link's CURVE keys, one pair for the ship and one per module."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from camcal.cli.common import DataOption, console, fail
from camcal.cli.config import settings_or_fail

app = typer.Typer(
    help="The module link's keys (ZeroMQ CURVE): one pair for the ship, one per module.",
    no_args_is_help=True,
)

KeysDirOption = Annotated[
    Path | None, typer.Option("--keys", help="Keys folder [CAMCAL_KEYS_DIR; default <data>/keys].")
]


def register(parent: typer.Typer) -> None:
    parent.add_typer(app, name="keys")


def _folder(keys: Path | None, data: Path | None) -> Path:
    return settings_or_fail(data_dir=data, keys_dir=keys).keys_path()


@app.command("create")
def create(
    modules: Annotated[list[str] | None, typer.Argument(help="Module ids to make a key pair for.")] = None,
    keys: KeysDirOption = None,
    data: DataOption = None,
    force: Annotated[
        bool, typer.Option(help="Replace existing keys (modules holding the old ones are refused).")
    ] = False,
) -> None:
    """Create the ship's key pair (once) and a key pair for each module named.

    Give each module a copy of ship.key and its own modules/<id>.key_secret,
    in a keys folder of the same layout, then delete the module's secret
    file from the ship. A running ingest lets a new module key in at once.
    """
    from camcal.core import wire
    from camcal.core.wire.keys import create_module_key, create_ship_key

    folder = _folder(keys, data)
    try:
        made = [create_ship_key(folder, force=force)]
        made += [create_module_key(folder, m, force=force) for m in modules or []]
    except wire.KeyFileError as exc:
        raise fail(str(exc)) from None
    except OSError as exc:
        raise fail(f"cannot write keys in {folder}: {exc}") from None
    for path in made:
        console.print(f"{path}  (secret: {path.name}_secret)", highlight=False)
    for m in modules or []:
        console.print(
            f"module {m}: copy {folder / 'ship.key'} and {folder / 'modules' / (m + '.key_secret')} to its "
            f"keys folder (same names), then delete {m}.key_secret here",
            highlight=False,
        )


@app.command("list")
def list_(keys: KeysDirOption = None, data: DataOption = None) -> None:
    """The ship's key and every module key the ship lets in: owner, public key (Z85), secret here or not."""
    from camcal.core.wire.keys import list_keys

    folder = _folder(keys, data)
    found = list_keys(folder)
    if not found:
        raise fail(f"no keys in {folder}: create them with `camcal keys create A B --keys {folder}`")
    console.print(f"keys in {folder}:", highlight=False, soft_wrap=True)
    width = max(len(k.owner) for k in found)
    for k in found:
        secret = "secret here" if k.has_secret else "public only"
        console.print(
            f"  {k.owner:<{width}}  {k.public}  {secret}  {k.path}",
            highlight=False,
            soft_wrap=True,
        )
