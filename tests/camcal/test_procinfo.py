"""What /proc says about ports and processes: real sockets of this test process."""

from __future__ import annotations

import os
import socket
from pathlib import Path

import pytest

from camcal.core import procinfo, supervise

pytestmark = pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="Linux /proc")


@pytest.mark.parametrize(
    ("family", "host", "listen"),
    [
        (socket.AF_INET, "127.0.0.1", True),
        (socket.AF_INET, "127.0.0.1", False),
        (socket.AF_INET6, "::1", True),
    ],
    ids=["ipv4-listening", "ipv4-bound-only", "ipv6-listening"],
)
def test_a_held_port_names_this_process(family: int, host: str, listen: bool) -> None:
    try:
        s = socket.socket(family, socket.SOCK_STREAM)
        s.bind((host, 0))
    except OSError:
        pytest.skip(f"no {host} here")
    with s:
        if listen:
            s.listen()
        port = s.getsockname()[1]
        uses = procinfo.port_uses(port)
        if listen:
            assert [u.port for u in uses] == [port]
            expected = "0000:0000:0000:0000:0000:0000:0000:0001" if family == socket.AF_INET6 else host
            assert uses[0].address == expected
            assert f"pid {os.getpid()} (" in procinfo.describe_holder(port)
        else:  # Linux lists no socket that is only bound: the port is taken, by nobody it can name
            assert uses == [] and procinfo.describe_holder(port) == ""
        with pytest.raises(supervise.PortInUse) as err:
            supervise.check_port("127.0.0.1" if family == socket.AF_INET else "::1", port, part="ingest",
                                 setting="--bind")  # fmt: skip
        message = str(err.value)
        assert f"the ingest cannot listen on {host if family == socket.AF_INET else '::1'}:{port}" in message
        assert (f"the port is in use by pid {os.getpid()} (" if listen else "the port is in use. ") in message
        assert message.endswith("choose another port with --bind.")
    assert procinfo.port_uses(port) == [] and procinfo.describe_holder(port) == ""


def test_a_free_port_passes_and_stays_free() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    supervise.check_port("127.0.0.1", port, part="dashboard", setting="--port")
    supervise.check_port("127.0.0.1", port, part="dashboard", setting="--port")  # left free the first time


def test_endpoints_name_their_port() -> None:
    assert supervise.tcp_endpoint("tcp://*:5555") == ("0.0.0.0", 5555)
    assert supervise.tcp_endpoint("tcp://127.0.0.1:5556") == ("127.0.0.1", 5556)
    assert supervise.tcp_endpoint("tcp://127.0.0.1:*") is None  # a port the system picks
    assert supervise.tcp_endpoint("ipc:///tmp/x") is None
