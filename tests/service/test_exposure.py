"""A service reachable from the network is never open: the decision from the zenoh config alone, and
``pvtflow serve``'s refusal before it opens anything (nothing here listens beyond loopback)."""

from __future__ import annotations

import json

import pytest
import zenoh
from svc_helpers import CONFIGS, free_port, served_cell

import pvtflow.service.serve_cmd
from pvtflow.service.cli import main
from pvtflow.service.exposure import exposure, is_local_endpoint
from pvtflow.service.serve_cmd import banner
from pvtflow.service.server import load_zenoh_config

ZENOH = CONFIGS / "zenoh"
NO_SCOUTING = {"multicast": {"enabled": False}, "gossip": {"enabled": False}}
AUTH = {"usrpwd": {"user": "svc", "password": "pw", "dictionary_file": "/etc/pvtflow/credentials.txt"}}
ACL = {"enabled": True, "default_permission": "deny", "rules": [], "subjects": [], "policies": []}


def config(**data: object) -> zenoh.Config:
    return zenoh.Config.from_json5(json.dumps(data))


@pytest.mark.parametrize(
    ("endpoint", "local"),
    [
        ("tcp/127.0.0.1:7447", True),
        ("tcp/127.3.2.1:7447", True),
        ("tcp/[::1]:7447", True),
        ("tcp/localhost:7447", True),
        ("udp/127.0.0.1:7447#iface=lo", True),
        ("tls/127.0.0.1:7447?prio=1", True),
        ("unixsock-stream//tmp/pvtflow.sock", True),
        ("tcp/0.0.0.0:7447", False),
        ("tcp/[::]:0", False),
        ("tcp/192.168.1.20:7447", False),
        ("tls/cell1.factory.example:7447", False),  # a name may resolve anywhere
        ("quic/10.0.0.1:7447", False),
        ("serial//dev/ttyUSB0#baudrate=115200", False),
    ],
)
def test_which_endpoints_stay_on_this_host(endpoint, local):
    assert is_local_endpoint(endpoint) is local


def test_the_shipped_service_configs_pass_and_loopback_needs_no_authentication():
    for name in ("service.json5", "access-control.json5"):
        exposed = exposure(load_zenoh_config(ZENOH / name))
        assert exposed.reachable == () and not exposed.open, name
    assert exposure(load_zenoh_config(ZENOH / "access-control.json5")).protected
    assert not exposure(load_zenoh_config(ZENOH / "service.json5")).protected


@pytest.mark.parametrize(
    ("data", "reachable"),
    [
        ({"listen": {"endpoints": ["tcp/0.0.0.0:7447"]}, "scouting": NO_SCOUTING}, ["listen tcp/0.0.0.0:7447"]),
        (
            {"listen": {"endpoints": ["tcp/127.0.0.1:7447"]}, "connect": {"endpoints": ["tcp/10.1.1.1:7447"]}}
            | {"scouting": NO_SCOUTING},
            ["connect tcp/10.1.1.1:7447"],
        ),
        (  # zenoh's defaults: a peer listens on every interface and scouts by multicast
            {},
            ["listen tcp/[::]:0", "multicast scouting udp/224.0.0.224:7446"],
        ),
        (
            {"listen": {"endpoints": ["tcp/127.0.0.1:7447"]}},
            ["multicast scouting udp/224.0.0.224:7446"],
        ),
        (
            {"mode": "router", "listen": {"endpoints": {"router": ["tcp/[::]:7447"], "peer": ["tcp/127.0.0.1:1"]}}}
            | {"scouting": NO_SCOUTING},
            ["listen tcp/[::]:7447"],
        ),
    ],
)
def test_a_config_reaching_beyond_this_host_is_open_without_authentication_and_access_control(data, reachable):
    exposed = exposure(config(**data))
    assert list(exposed.reachable) == reachable
    assert exposed.open
    refusal = exposed.refusal("zenoh config X")
    assert reachable[0] in refusal and "--allow-unauthenticated" in refusal
    assert "access-control.json5" in refusal
    # both authentication and access control close it; either alone does not
    assert not exposure(config(**data, transport={"auth": AUTH}, access_control=ACL)).open
    only_auth = exposure(config(**data, transport={"auth": AUTH}))
    assert only_auth.open  # the refusal names what is missing, and only that
    assert "access control (" in only_auth.refusal("X") and "authentication (" not in only_auth.refusal("X")
    assert exposure(config(**data, access_control=ACL)).open
    assert exposure(
        config(**data, transport={"auth": AUTH}, access_control={**ACL, "default_permission": "allow"})
    ).open


def test_the_shipped_access_control_config_on_all_interfaces_is_not_open(tmp_path):
    text = (ZENOH / "access-control.json5").read_text().replace("tcp/127.0.0.1:7447", "tcp/0.0.0.0:7447")
    file = tmp_path / "lan.json5"
    file.write_text(text)
    exposed = exposure(load_zenoh_config(file))
    assert exposed.reachable == ("listen tcp/0.0.0.0:7447",) and exposed.protected and not exposed.open


@pytest.fixture
def nothing_opens(monkeypatch):
    """Fails the test if serve gets as far as the bus or zenoh (the refusal must come before)."""

    def opened(*args: object, **kwargs: object) -> None:
        raise AssertionError("serve opened the cell or zenoh despite an open zenoh config")

    monkeypatch.setattr(pvtflow.service.serve_cmd, "MotionService", opened)
    monkeypatch.setattr(pvtflow.service.serve_cmd, "Server", opened)


def test_serve_refuses_an_open_config_before_opening_anything(tmp_path, capsys, nothing_opens):
    file = tmp_path / "lan.json5"
    file.write_text((ZENOH / "service.json5").read_text().replace("tcp/127.0.0.1:7447", "tcp/0.0.0.0:7447"))
    assert main(["serve", "--zenoh-config", str(file)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith("pvtflow serve: zenoh config ") and str(file) in err
    assert "listen tcp/0.0.0.0:7447" in err and "--allow-unauthenticated" in err


def test_allow_unauthenticated_gets_past_the_check_and_the_banner_says_so(arm6, tmp_path, capsys, monkeypatch):
    file = tmp_path / "lan.json5"
    file.write_text((ZENOH / "service.json5").read_text().replace("tcp/127.0.0.1:7447", "tcp/0.0.0.0:7447"))
    reached: list[str] = []

    def stop_here(*args: object, **kwargs: object) -> None:
        reached.append("service")
        raise ValueError("stopped by the test before the bus opens")

    monkeypatch.setattr(pvtflow.service.serve_cmd, "MotionService", stop_here)
    assert main(["serve", "--zenoh-config", str(file), "--allow-unauthenticated"]) == 2
    assert reached == ["service"]  # the exposure check let it through
    assert "stopped by the test" in capsys.readouterr().err
    monkeypatch.undo()

    # the banner: a served cell on loopback, shown with the open config it would have been given
    port = free_port()
    with served_cell(arm6, tmp_path / "journal", port=port) as s:
        assert "--allow-unauthenticated" not in banner(s.service, s.server)
        assert "needs no exception" in banner(s.service, s.server, allow_unauthenticated=True)

        class OnTheLan:  # what the banner reads of a server
            config = load_zenoh_config(file)
            listen_endpoints = ("tcp/0.0.0.0:7447",)

        text = banner(s.service, OnTheLan, allow_unauthenticated=True)  # type: ignore[arg-type]
        assert "--allow-unauthenticated: anyone who reaches listen tcp/0.0.0.0:7447 can execute motions" in text
