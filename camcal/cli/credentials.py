"""Secrets of the running system: operator tokens, the link keys of simulated modules, children's environment.

Tokens come from the configuration (``CAMCAL_OPERATOR_TOKENS``, or a file
named by ``operator_tokens_file``), never need to be on a command line, and
are printed only when camcal made one up itself. Child processes (the
ingest, simulated modules) need none of them: their environment is scrubbed.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path
from typing import TYPE_CHECKING

from camcal.cli.common import err_console, fail, labelled

if TYPE_CHECKING:
    from camcal.core.settings import Settings

#: Environment variables the children of ``camcal up`` never get.
SECRET_VARIABLES = ("CAMCAL_OPERATOR_TOKENS", "CAMCAL_OPERATOR_TOKENS_FILE")


def operator_tokens(items: list[str] | None, settings: Settings) -> dict[str, str]:
    """Configured tokens (``CAMCAL_OPERATOR_TOKENS``, ``operator_tokens_file``) plus ``NAME=TOKEN``."""
    try:
        out = settings.tokens()
    except ValueError as exc:
        raise fail(str(exc)) from None
    if items:
        err_console.print(
            labelled(
                "warning:",
                "yellow",
                "--operator-token shows the token to every user of this machine (ps); "
                "use CAMCAL_OPERATOR_TOKENS or operator_tokens_file instead",
            ),
            highlight=False,
        )
    for item in items or []:
        name, sep, token = item.strip().partition("=")
        if not sep or not name or len(token) < 8:
            raise fail("--operator-token: give NAME=TOKEN with a token of at least 8 characters")
        out[name] = token
    for name, token in out.items():
        if len(token) < 8:
            raise fail(f"operator token of {name!r} is shorter than 8 characters")
    return out


def tokens_or_generated(items: list[str] | None, settings: Settings) -> tuple[dict[str, str], bool]:
    """The configured tokens, or one made up for an ``operator`` (then True: it may be printed)."""
    tokens = operator_tokens(items, settings)
    if tokens:
        return tokens, False
    return {"operator": secrets.token_urlsafe(18)}, True


def child_environment() -> dict[str, str]:
    """This process's environment without the operator tokens: what a child process gets."""
    return {k: v for k, v in os.environ.items() if k not in SECRET_VARIABLES}


def ship_key(settings: Settings) -> None:
    """The ship's own key pair, made on first start (like a host key): without module keys (`camcal
    keys create A B`) nothing can connect yet, but the ingest starts and says so."""
    if settings.link_plaintext:
        return
    from camcal.core import wire
    from camcal.core.wire.keys import create_ship_key

    folder: Path = settings.keys_path()
    try:
        create_ship_key(folder)
    except (OSError, wire.KeyFileError) as exc:
        raise fail(f"cannot create the ship's link key in {folder}: {exc}") from None


def simulated_link(settings: Settings, modules: list[str]) -> list[str]:
    """Make sure the keys of the ship and of simulated ``modules`` exist; the modules' link options.

    ``camcal up`` stays one command: on first start it creates the keys in
    the data folder (``keys/``), later starts use them. With
    ``link_plaintext`` no keys are made and the modules are told so.
    """
    if settings.link_plaintext:
        return ["--plaintext"]
    from camcal.core import wire
    from camcal.core.wire.keys import create_module_key, create_ship_key

    folder: Path = settings.keys_path()
    try:
        create_ship_key(folder)
        for m in modules:
            create_module_key(folder, m)
    except (OSError, wire.KeyFileError) as exc:
        raise fail(f"cannot create the link keys in {folder}: {exc}") from None
    return ["--keys", str(folder)]
