"""What `camcal up` tells the operator about where modules connect, as the ingest really listens."""

from __future__ import annotations

from camcal.cli.up import _modules_connect


def test_an_ingest_on_the_loopback_says_only_this_machine_and_how_to_open_it() -> None:
    text = _modules_connect("127.0.0.1", 5555)
    assert "on this machine connect to tcp://127.0.0.1:5555" in text
    assert "--ingest-host 0.0.0.0" in text  # "<this host>" was printed, which modules elsewhere cannot use


def test_an_ingest_on_every_address_or_one_names_it() -> None:
    assert _modules_connect("0.0.0.0", 5600) == "modules connect to tcp://<this host's address>:5600"
    assert _modules_connect("10.0.3.7", 5555) == "modules connect to tcp://10.0.3.7:5555"
