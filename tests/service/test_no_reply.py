"""A request nobody answers says why: another cell's service is there (named, with the --cell that
reaches it), none is, or the cell's own service did not answer in time (service/request_cmd.py)."""

from __future__ import annotations

from pvtflow.service.cli import main


def test_a_request_to_a_cell_nobody_serves_names_the_cells_that_are_there(serve, gantry3, capsys) -> None:  # type: ignore[no-untyped-def]
    served = serve(gantry3)
    assert main(["request", "status", "--connect", served.endpoint, "--timeout", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "no service of cell arm6 is reachable" in err[0] and "serve gantry3 (--cell gantry3)" in err[0], err
    reply = served.client.request("arm6", "status", timeout=1.0)
    assert reply.error_code == "no_reply" and "--cell gantry3" in reply.data["error"]["message"]
    assert main(["request", "status", "--connect", served.endpoint, "--cell", "gantry3"]) == 0
