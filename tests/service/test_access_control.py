"""The shipped access-control config: only the operator may execute, stop and recover (loopback)."""

from __future__ import annotations

import json

import pytest
import zenoh
from svc_helpers import CONFIGS, SHORT_TARGET, free_port, nothing_moved, wait_until

from pvtflow.service.request_cmd import Client
from pvtflow.service.server import load_zenoh_config

ZENOH = CONFIGS / "zenoh"


def shipped(name: str, **endpoints: list[str]) -> zenoh.Config:
    """A shipped config file with only its endpoints (and the dictionary's absolute path) changed."""
    config = load_zenoh_config(ZENOH / name)
    for which, value in endpoints.items():
        config.insert_json5(f"{which}/endpoints", json.dumps(value))
    if name == "access-control.json5":
        config.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(ZENOH / "credentials.txt")))
    return config


@pytest.mark.wall
def test_only_the_operator_may_command_and_a_denied_caller_gets_nothing(arm6, serve):
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    s = serve(
        arm6,
        zconfig=shipped("access-control.json5", listen=[endpoint]),
        port=port,
        client_zconfig=shipped("operator-client.json5", connect=[endpoint]),
    )
    operator = s.client
    observer = Client(shipped("observer-client.json5", connect=[endpoint]))
    try:
        # the observer may look, follow and plan...
        seen: list[dict] = []
        sub = observer.follow("arm6", "telemetry", lambda cell, data: seen.append(data))
        assert wait_until(lambda: len(seen) > 0, timeout=5)  # idle telemetry reaches it
        del sub
        assert observer.alive("arm6") == ["arm6"]
        assert observer.request("arm6", "status").ok
        plan = observer.request("arm6", "plan", {"target": SHORT_TARGET})
        assert plan.ok, plan.data
        # ...but its commands never reach the service: no reply at all, and nothing moves
        commands = (("execute", {"plan_id": plan.data["plan_id"]}), ("stop", {}), ("recover", {}), ("home", {}))
        for op, payload in commands:
            assert observer.replies("arm6", op, payload, timeout=1.5) == [], op
        nothing_moved(s)

        # the operator's execute runs
        done = operator.request("arm6", "execute", {"plan_id": plan.data["plan_id"], "wait": True})
        assert done.ok and done.data["outcome"]["result"] == "finished", done.data
        assert operator.request("arm6", "stop").ok
        home = operator.request("arm6", "home")  # reaches the service (arm6 has nothing to home)
        assert home.data["error"]["code"] == "not_allowed", home.data
        assert [e.motion_id for e in s.service.journal.recent(5)] == [done.data["motion_id"]]
    finally:
        observer.close()

    # without credentials, or with a wrong password, there is no session at all
    anonymous = shipped("client.json5", connect=[endpoint])
    impostor = shipped("operator-client.json5", connect=[endpoint])
    impostor.insert_json5("transport/auth/usrpwd/password", json.dumps("guess"))
    for config in (anonymous, impostor):
        with pytest.raises(zenoh.ZError):
            Client(config).close()
