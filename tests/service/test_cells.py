"""Two cells, two services, one zenoh network: one client addresses both through pvtflow/*/..."""

from __future__ import annotations

import json

import zenoh
from svc_helpers import check_reply, free_port, wait_until

from pvtflow.service.request_cmd import Client
from pvtflow.service.server import client_config, peer_config


def router(port: int) -> zenoh.Session:
    """A zenoh router on loopback (what zenohd with configs/zenoh/router.json5 is), scouting off."""
    return zenoh.open(
        zenoh.Config.from_json5(
            json.dumps(
                {
                    "mode": "router",
                    "listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
                    "connect": {"endpoints": []},
                    "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
                }
            )
        )
    )


def test_two_cells_on_one_network_answer_one_wildcard_request(arm6, gantry3, serve):
    hub = f"tcp/127.0.0.1:{free_port()}"
    r = router(int(hub.rsplit(":", 1)[1]))
    try:
        client = Client(client_config([hub]))  # clients reach peers behind a router in client mode
        try:
            a = serve(arm6, zconfig=peer_config(listen=[f"tcp/127.0.0.1:{free_port()}"], connect=[hub]), client=client)
            b = serve(
                gantry3, zconfig=peer_config(listen=[f"tcp/127.0.0.1:{free_port()}"], connect=[hub]), client=client
            )
            assert wait_until(lambda: client.alive("*", timeout=0.5) == ["arm6", "gantry3"], timeout=10)

            replies = client.replies("*", "status", {"recent": 0}, timeout=10)
            by_cell = {rep.cell: rep for rep in replies}
            assert set(by_cell) == {"arm6", "gantry3"}
            for cell, rep in by_cell.items():
                assert rep.ok and rep.data["cell"] == cell
                check_reply("status", rep.data)
            assert len(by_cell["arm6"].data["axes"]) == 6 and len(by_cell["gantry3"].data["axes"]) == 3

            # each cell plans and moves on its own bus: a move on gantry3 leaves arm6 untouched (the
            # gantry homes first: its encoders are incremental)
            homed = client.request("gantry3", "home", {"wait": True}, timeout=60)
            assert homed.ok and homed.data["outcome"]["result"] == "homed", homed.data
            plan = client.request("gantry3", "plan", {"target": [0.2, 0.1, -0.05]})
            assert plan.ok, plan.data
            done = client.request("gantry3", "execute", {"plan_id": plan.data["plan_id"], "wait": True})
            assert done.ok and done.data["outcome"]["result"] == "finished", done.data
            assert all(d.records_received == 0 for d in a.sim)
            assert any(d.records_received > 0 for d in b.sim)
            # a plan id belongs to its cell
            wrong = client.request("arm6", "execute", {"plan_id": plan.data["plan_id"]})
            assert wrong.data["error"]["code"] == "unknown_plan"

            # a service that goes away takes its liveliness token with it
            b.server.close()
            assert wait_until(lambda: client.alive("*", timeout=0.5) == ["arm6"], timeout=10)
            assert [rep.cell for rep in client.replies("*", "status", timeout=5)] == ["arm6"]
        finally:
            client.close()
    finally:
        r.close()
