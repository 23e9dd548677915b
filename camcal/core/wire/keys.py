"""The link's CURVE keys: one pair for the ship, one pair per module, kept in a keys folder.

ZeroMQ CURVE (elliptic-curve encryption and authentication, built into
libzmq) secures the module link: the ship proves it holds the ship's secret
key, each module proves it holds its own, and everything on the wire is
encrypted. The ship knows a module by its public key, never by what a
message says. Layout of a keys folder (``camcal keys create`` writes it)::

    keys/ship.key                the ship's public key: every module needs a copy
    keys/ship.key_secret         the ship's secret key: stays on the ship
    keys/modules/A.key           module A's public key: the ship lets this key in as module A
    keys/modules/A.key_secret    module A's secret key: belongs on module A only

A module's keys folder holds the same names: ``ship.key`` and its own
``modules/<id>.key_secret``. The files are ZeroMQ certificates (text, the
keys in Z85); secret files are readable by their owner only.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import zmq.auth
import zmq.utils.z85

from camcal.core.wire.models import is_id

SHIP = "ship"


class KeyFileError(Exception):
    """A key that is missing or unreadable, with what to do about it."""


@dataclass(frozen=True)
class KeyPair:
    """A CURVE key pair, each key in Z85 (40 characters)."""

    public: bytes
    secret: bytes


@dataclass(frozen=True)
class ModuleKeys:
    """What a module needs to connect: its own pair and the ship's public key."""

    module: str
    pair: KeyPair
    ship_public: bytes


@dataclass(frozen=True)
class KeyInfo:
    """One key of a keys folder, as `list_keys` shows it."""

    owner: str  # "ship" or a module id
    public: str
    has_secret: bool
    path: Path


def _ship_file(keys_dir: Path) -> Path:
    return Path(keys_dir) / f"{SHIP}.key"


def _module_file(keys_dir: Path, module: str) -> Path:
    return Path(keys_dir) / "modules" / f"{module}.key"


def _create(folder: Path, name: str, *, force: bool) -> Path:
    public = folder / f"{name}.key"
    if public.exists() and not force:
        return public
    folder.mkdir(parents=True, exist_ok=True)
    os.chmod(folder, 0o700)
    old = os.umask(0o077)  # the secret file is never readable by others, not even for a moment
    try:
        public_file, _secret_file = zmq.auth.create_certificates(str(folder), name)
    finally:
        os.umask(old)
    os.chmod(public_file, 0o644)
    return Path(public_file)


def create_ship_key(keys_dir: Path, *, force: bool = False) -> Path:
    """The ship's key pair in ``keys_dir`` (kept if it exists, unless ``force``); its public file."""
    Path(keys_dir).mkdir(parents=True, exist_ok=True)
    os.chmod(keys_dir, 0o700)
    return _create(Path(keys_dir), SHIP, force=force)


def create_module_key(keys_dir: Path, module: str, *, force: bool = False) -> Path:
    """Module ``module``'s key pair under ``keys_dir/modules`` (kept if it exists); its public file."""
    if not is_id(module) or module == SHIP:
        raise KeyFileError(
            f"{module!r} is not a module id (1-64 letters, digits, _ . -, not only dots, not 'ship')"
        )
    return _create(Path(keys_dir) / "modules", module, force=force)


def _load(path: Path, *, secret: bool, what: str, fix: str) -> tuple[bytes, bytes | None]:
    name = path.with_name(path.name + "_secret") if secret else path
    if not name.is_file():
        raise KeyFileError(f"no {what} at {name}: {fix}")
    try:
        public, secret_key = zmq.auth.load_certificate(str(name))
    except (OSError, ValueError) as exc:
        raise KeyFileError(f"{name}: not a readable key file ({exc}): {fix}") from None
    if secret and not secret_key:
        raise KeyFileError(f"{name} holds no secret key: {fix}")
    return public, secret_key


def ship_pair(keys_dir: Path) -> KeyPair:
    """The ship's key pair (for the ingest)."""
    public, secret = _load(
        _ship_file(keys_dir),
        secret=True,
        what="ship key pair",
        fix=f"run `camcal keys create --keys {keys_dir}` on the ship",
    )
    assert secret is not None
    return KeyPair(public, secret)


def ship_public(keys_dir: Path) -> bytes:
    """The ship's public key (what every module needs)."""
    public, _ = _load(
        _ship_file(keys_dir),
        secret=False,
        what="ship's public key",
        fix=f"copy the ship's keys/ship.key to {keys_dir}",
    )
    return public


def module_keys(keys_dir: Path, module: str) -> ModuleKeys:
    """What module ``module`` needs: its key pair and the ship's public key."""
    fix = (
        f"run `camcal keys create {module} --keys DIR` on the ship and copy DIR/ship.key and "
        f"DIR/modules/{module}.key_secret to {keys_dir} on the module"
    )
    what = f"key of module {module}"
    public, secret = _load(_module_file(keys_dir, module), secret=True, what=what, fix=fix)
    ship_public, _ = _load(_ship_file(keys_dir), secret=False, what="ship's public key", fix=fix)
    assert secret is not None
    return ModuleKeys(module, KeyPair(public, secret), ship_public)


def authorised_modules(keys_dir: Path) -> dict[bytes, str]:
    """Public key (Z85) -> module id, for every module key the ship lets in."""
    folder = Path(keys_dir) / "modules"
    out: dict[bytes, str] = {}
    for path in sorted(folder.glob("*.key")) if folder.is_dir() else []:
        module = path.stem
        if not is_id(module):
            continue
        public, _ = _load(path, secret=False, what=f"key of module {module}", fix="remove or recreate it")
        out[public] = module
    return out


def list_keys(keys_dir: Path) -> list[KeyInfo]:
    """The ship's key and every module key of a keys folder."""
    out = []
    paths = [_ship_file(keys_dir), *sorted((Path(keys_dir) / "modules").glob("*.key"))]
    for path in paths:
        if not path.is_file():
            continue
        try:
            public, _ = zmq.auth.load_certificate(str(path))
        except (OSError, ValueError):
            continue
        owner = SHIP if path == _ship_file(keys_dir) else path.stem
        has_secret = path.with_name(path.name + "_secret").is_file()
        out.append(KeyInfo(owner, public.decode(), has_secret, path))
    return out


def fingerprint(public: bytes | str) -> str:
    """A short name for a public key in logs and on the dashboard (its first 8 Z85 characters)."""
    text = public.decode(errors="replace") if isinstance(public, bytes) else public
    return text[:8] + "…"


def z85_of(raw: bytes) -> bytes:
    """A 32-byte raw CURVE key (as ZAP hands it over) in Z85."""
    return zmq.utils.z85.encode(raw)
