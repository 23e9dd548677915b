"""The conformance kits: ``camcal lrm conformance`` (a module checks a ship) and ``camcal ingest
--conformance`` (a ship checks a module), each printing pass or fail per rule of docs/protocol.md."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from camcal.cli.common import console, fail


def _module_of(keys: Path) -> str:
    """The one module whose key pair a module's keys folder holds."""
    found = sorted(p.name.removesuffix(".key_secret") for p in (keys / "modules").glob("*.key_secret"))
    if len(found) != 1:
        what = f"the key pairs of {', '.join(found)}" if found else "no module key pair"
        raise fail(
            f"{keys}/modules holds {what}: say which module to be with --module ID "
            f"(a module's keys folder holds ship.key and modules/<id>.key_secret)"
        )
    return found[0]


def print_report(report: Any) -> None:
    for line in report.lines():
        style = "red" if " fail " in line[:20] else ("green" if " pass " in line[:20] else None)
        console.print(line, style=style, highlight=False, soft_wrap=True)


def lrm_conformance(
    ship: Annotated[str, typer.Argument(help="The ship's ingest: tcp://SHIP:PORT.")],
    keys: Annotated[
        Path | None,
        typer.Option(
            help="A module's keys folder: ship.key and modules/<id>.key_secret (`camcal keys create`)."
        ),
    ] = None,
    module: Annotated[
        str | None, typer.Option(help="The module to be (default: the one whose key pair --keys holds).")
    ] = None,
    plaintext: Annotated[bool, typer.Option(help="The ship runs a plaintext link (a lab bench).")] = False,
    dive: Annotated[str | None, typer.Option(help="The dive the ship records (default: whichever).")] = None,
) -> None:
    """Check that a ship keeps the protocol: pass or fail per numbered rule of docs/protocol.md.

    Stores a few small frames under the module's id and a boot of its own: run it against a
    ship that records a test dive. Exit status 0 when no rule is broken, 1 otherwise."""
    from camcal.core import wire
    from lrm.conformance import ShipConformance

    if not ship.startswith("tcp://"):
        raise fail(f"{ship!r}: give the ship's ingest as tcp://HOST:PORT (its --bind)")
    if plaintext:
        if module is None:
            raise fail("on a plaintext link say which module to be: --module ID")
        module_keys = None
    else:
        if keys is None:
            raise fail(
                "give the module's keys folder with --keys DIR (or --plaintext for a lab bench's ship)"
            )
        module = module or _module_of(keys)
        try:
            module_keys = wire.module_keys(keys, module)
        except wire.KeyFileError as exc:
            raise fail(str(exc)) from None
    console.print(f"checking the ship at {ship} as module {module} (docs/protocol.md, 'The rules')")
    report = ShipConformance(ship, module, module_keys, dive).run()
    print_report(report)
    if not report.passed:
        raise typer.Exit(1)


def ingest_conformance(
    bind: str, keys_dir: Path | None, plaintext: bool, dive: str | None, duration_s: float
) -> None:
    """`camcal ingest --conformance`: a ship that stores nothing checks the module that connects to it."""
    import zmq

    from camcal.core import supervise, wire
    from ingest.conformance import ModuleConformance
    from ingest.counters import Counters
    from ingest.gatekeeper import Gatekeeper

    supervise.check_endpoint(bind, part="conformance ship", setting="--bind (CAMCAL_INGEST_BIND)")
    ctx: zmq.Context[Any] = zmq.Context()
    gate = None
    try:
        keys = None
        if not plaintext:
            if keys_dir is None:
                raise fail("the link needs keys: create them with `camcal keys create A` (or --plaintext)")
            try:
                keys = wire.ship_pair(keys_dir)
            except wire.KeyFileError as exc:
                raise fail(str(exc)) from None
            gate = Gatekeeper(ctx, keys_dir, Counters())
        router = wire.ship_socket(ctx, bind, keys=keys)
        endpoint = router.getsockopt(zmq.LAST_ENDPOINT).decode()
        console.print(
            f"conformance: a ship that stores nothing listens on {endpoint}; start the module now "
            f"(checking for {duration_s:g} s at most, docs/protocol.md, 'The rules')"
        )
        checker = ModuleConformance(
            router,
            list(gate.sockets) if gate else [],
            gate.handle if gate else (lambda: None),
            dive,
            duration_s,
        )
        report = checker.run()
        router.close(0)
    finally:
        if gate is not None:
            gate.close()
        ctx.term()
    console.print(f"module {checker.module or '(none connected)'}:")
    print_report(report)
    if not report.passed or not checker.module:
        raise typer.Exit(1)
