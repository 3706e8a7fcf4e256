"""What a new user typed (issue 19): every mistake gets one clear line and exit 2 before anything starts,
and what the service accepts, the command line accepts (one waypoint, a target whose first value is
negative). Real zenoh sessions on loopback, simulated drives."""

from __future__ import annotations

import json
import shlex
import socket
import tempfile

import numpy as np
import pytest
from svc_helpers import CONFIGS, free_port, served_cell

from pvtflow.service.cli import build_parser, join_negative_values, main, one_value_options, subcommand_parsers
from pvtflow.service.serve_cmd import banner, example_target
from pvtflow.service.server import load_zenoh_config

ZENOH = CONFIGS / "zenoh"
ARM6_TARGET = [-0.3, 0.2, -0.3, 0.2, -0.3, 0.2]  # its first value negative


def one_line(err: str) -> str:
    """The single line a refused command printed (and proof that it was one line, not a traceback)."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture(scope="module")
def served(arm6, tmp_path_factory):
    with served_cell(arm6, tmp_path_factory.mktemp("journal")) as s:
        yield s


# --- refused before anything starts ----------------------------------------------------------------------
def test_an_endpoint_without_protocol_is_one_line_and_exit_2(capsys) -> None:
    assert main(["request", "status", "--connect", "127.0.0.1:7447"]) == 2
    line = one_line(capsys.readouterr().err)
    assert "not a zenoh endpoint" in line and "tcp/127.0.0.1:7447" in line


@pytest.mark.parametrize("command", ["serve", "execute"])
def test_a_can_log_of_unknown_format_is_refused_before_anything_starts(tmp_path, capsys, command) -> None:
    log = tmp_path / "can.xyz"
    argv = ["serve", "--journal", str(tmp_path / "journal")] if command == "serve" else ["execute", "nothing.json"]
    assert main([*argv, "--can-log", str(log)]) == 2
    line = one_line(capsys.readouterr().err)
    assert f"cannot write the CAN log {log}: unknown log format '.xyz'" in line, line
    assert ".blf" in line  # what python-can writes instead
    assert not log.exists() and not (tmp_path / "journal").exists()  # nothing started, nothing written
    assert main([*argv, "--can-log", str(tmp_path / "no-such-dir" / "can.log")]) == 2
    assert "is not a directory" in one_line(capsys.readouterr().err)


def test_request_mistakes_are_refused_before_a_session_opens(tmp_path, capsys) -> None:
    """Nothing listens on the endpoint: a command that got as far as zenoh would say it cannot reach it."""
    nowhere = ["--connect", f"tcp/127.0.0.1:{free_port()}", "--timeout", "1"]
    notjson = tmp_path / "notjson.json"
    notjson.write_text("hello")
    program = tmp_path / "program.json"
    program.write_text("{}")
    cases = [
        (["execute", "--program", str(tmp_path / "nofile.json")], f"{tmp_path / 'nofile.json'}: file not found"),
        (["validate", "--program", str(notjson)], f"{notjson}: not JSON: "),
        (["validate", "--program", str(tmp_path)], f"{tmp_path}: is a directory"),
        (["plan", "--target", "0.1,0.2", "--waypoints", str(program)], "--target Q1,Q2,... or --waypoints FILE"),
        (["plan", "--target", "0.1,x"], "--target: not a comma-separated list of finite numbers"),
        (["plan", "--target", "0.1,nan"], "--target: not a comma-separated list of finite numbers"),
        (["plan"], "plan needs --waypoints FILE or --target"),
        (["execute", "p-0123", "--program", str(program)], "a PLAN_ID or --program FILE, not both"),
        (["stop", "--wait"], "--wait is for execute / home / resume, not stop"),
        (["override", "1.5"], "override takes a SCALE in [0.05, 1.0]"),
        (["override"], "override takes a SCALE in [0.05, 1.0]"),
        (["status", "--mode", "quick"], "--mode is for stop, not status"),
        (["status", "p-0123"], "PLAN_ID is for validate / execute, not status"),
        (["execute", "p-0123", "--target", "1,2"], "--target is for plan, not execute"),
        (["plan", "--target", "0.1,0.2", "--velocity-scale", "0"], "--velocity-scale must be in (0, 1], got 0"),
        (["plan", "--target", "0.1,0.2", "--acceleration-scale", "1.5"], "--acceleration-scale must be in (0, 1]"),
        (["plan", "--target", "0.1,0.2", "--velocity-scale", "nan"], "--velocity-scale must be in (0, 1], got nan"),
        (["status", "--velocity-scale", "0.5"], "--velocity-scale is for plan, not status"),
    ]
    for args, expected in cases:
        assert main(["request", *args, *nowhere]) == 2, args
        line = one_line(capsys.readouterr().err)
        assert expected in line and "cannot reach" not in line, (args, line)


def test_a_yaml_syntax_error_is_one_line_with_its_place(tmp_path, capsys) -> None:
    bad = tmp_path / "cell.yaml"
    bad.write_text("name: x\nbus:\n  interface: [virtual\naxes: []\n")
    assert main(["serve", "--config", str(bad), "--journal", str(tmp_path / "j")]) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith(f"pvtflow serve: {bad}: line 4, column 5: not valid YAML: expected ',' or ']'"), line
    assert "from line 3" in line
    tab = tmp_path / "tab.yaml"
    tab.write_text("name: x\n\tbus: 1\n")
    assert main(["plan", "--config", str(tab), "--waypoints", "w.json", "-o", str(tmp_path / "p.json")]) == 2
    assert f"{tab}: line 2, column 1: not valid YAML" in one_line(capsys.readouterr().err)


def test_every_one_value_option_takes_a_negative_leading_value() -> None:
    """argparse alone reads "-0.3,0.2" as an option; every option that takes a value gets it whole."""
    parser = build_parser()
    for name, sub in subcommand_parsers(parser).items():
        for option in one_value_options(sub):
            argv = join_negative_values([name, option, "-0.3,0.2", "--", "-1"], parser)
            assert argv == [name, f"{option}=-0.3,0.2", "--", "-1"], (name, option)
    assert join_negative_values(["request", "plan", "--wait", "-1,2"], parser)[2:] == ["--wait", "-1,2"]  # a flag
    args = parser.parse_args(join_negative_values(["request", "plan", "--target", "-.3,2e-1"], parser))
    assert args.target == "-.3,2e-1"


# --- accepted as the service accepts it ------------------------------------------------------------------
def test_a_negative_leading_target_and_a_single_waypoint_plan_and_the_outcome_says_where_the_axes_are(
    served, tmp_path, capsys
) -> None:
    connect = ["--connect", served.endpoint]
    assert main(["request", "plan", "--target", ",".join(map(str, ARM6_TARGET)), *connect]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert plan["end"] == ARM6_TARGET and plan["waypoints"] == 2

    one = tmp_path / "one.json"
    one.write_text(json.dumps({"waypoints": [[0.1, -0.1, 0.1, -0.1, 0.1, -0.1]]}))
    assert main(["request", "plan", "--waypoints", str(one), *connect]) == 0
    assert json.loads(capsys.readouterr().out)["waypoints"] == 2  # from where the axes are to it

    assert main(["request", "execute", plan["plan_id"], "--wait", *connect]) == 0
    outcome = json.loads(capsys.readouterr().out)["outcome"]
    assert outcome["result"] == "finished"
    for axis, goal in zip(outcome["axes"], ARM6_TARGET, strict=True):
        scaling = served.cell.axis_for_joint(axis["joint"]).scaling
        assert axis["position_qc"] == axis["target_position_qc"] == served.sim.drive(axis["node_id"]).actual
        assert axis["position"] == pytest.approx(float(scaling.qc_to_position(axis["position_qc"])))
        assert axis["position"] == pytest.approx(goal, abs=2.0 / scaling.qc_per_joint_unit)  # joint units


# --- what serve prints fits the cell ---------------------------------------------------------------------
def run_printed(
    text: str, request: str, capsys: pytest.CaptureFixture[str], timeout: float = 5.0, **replace: str
) -> tuple[int, str]:
    """Run the ``pvtflow request <request>`` line the banner printed, as a user would paste it."""
    line = next(x.strip() for x in text.splitlines() if x.strip().startswith(f"pvtflow request {request}"))
    for old, new in replace.items():
        line = line.replace(old, new)
    code = main([*shlex.split(line)[1:], "--timeout", f"{timeout:g}"])
    return code, capsys.readouterr().out


@pytest.mark.parametrize("cell_name", ["gantry3", "arm6"])
def test_the_printed_plan_command_fits_the_cell(cell_name, request, tmp_path, capsys) -> None:
    cell = request.getfixturevalue(cell_name)
    with served_cell(cell, tmp_path / "journal") as s:
        text = banner(s.service, s.server)
        plan_line = next(x for x in text.splitlines() if "pvtflow request plan" in x)
        target = [float(v) for v in plan_line.split("--target ")[1].split(",")]
        lim = s.service.limits
        assert np.all(np.asarray(lim.lower) < target) and np.all(target < np.asarray(lim.upper)), target
        assert target == example_target(lim.lower, lim.upper)
        if cell.requires_homing:  # the gantry's incremental encoders: the banner says to home first
            code, out = run_printed(text, "home", capsys, timeout=60.0)
            assert code == 0 and json.loads(out)["outcome"]["result"] == "homed", out
        code, out = run_printed(text, "plan", capsys)
        assert code == 0, out
        assert json.loads(out)["end"] == target


def test_the_banner_of_a_service_that_requires_credentials_prints_them(arm6, tmp_path, capsys) -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    zconfig = load_zenoh_config(ZENOH / "access-control.json5")
    zconfig.insert_json5("listen/endpoints", json.dumps([endpoint]))
    zconfig.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(ZENOH / "credentials.txt")))
    operator = load_zenoh_config(ZENOH / "operator-client.json5")
    operator.insert_json5("connect/endpoints", json.dumps([endpoint]))
    with served_cell(arm6, tmp_path / "journal", zconfig=zconfig, port=port, client_zconfig=operator) as s:
        text = banner(s.service, s.server)
        assert "clients must authenticate" in text and "credentials.txt" in text
        status = next(x for x in text.splitlines() if "pvtflow request status" in x)
        assert "observer-client.json5" in status and f"--connect {endpoint}" in status

        code, out = run_printed(text, "status", capsys)  # as printed: the observer's config, this endpoint
        assert code == 0 and json.loads(out)["cell"] == "arm6"
        code, out = run_printed(text, "plan", capsys)
        assert code == 0, out
        plan_id = json.loads(out)["plan_id"]
        code, out = run_printed(text, "execute", capsys, PLAN_ID=plan_id)  # the operator's config
        assert code == 0 and json.loads(out)["motion_id"]
        assert s.service.journal.recent(5)

        # without the credentials the same status command is refused at connection time
        assert main(["request", "status", "--cell", "arm6", "--connect", endpoint, "--timeout", "2"]) == 2
        assert "cannot reach the service" in capsys.readouterr().err


# --- the demo leaves nothing behind ----------------------------------------------------------------------
def test_the_demo_removes_its_temporary_journal_when_it_ran_and_when_it_could_not_start(
    tmp_path, capsys, monkeypatch
) -> None:
    temp = tmp_path / "tmp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    plot = tmp_path / "demo.png"
    assert main(["demo", "--plot", str(plot), "--tour-points", "1"]) == 0
    assert "outcome: finished" in capsys.readouterr().out and plot.exists()
    assert list(temp.iterdir()) == []
    with socket.socket() as taken:  # its zenoh port is in use: it cannot start, after the cell was up
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        assert main(["demo", "--plot", str(plot), "--port", str(taken.getsockname()[1])]) == 2
    assert "cannot open zenoh" in capsys.readouterr().err
    assert list(temp.iterdir()) == []


def test_the_old_demo_option_name_still_counts_tour_points() -> None:
    parser = build_parser()
    assert parser.parse_args(["demo"]).tour_points == 4
    assert parser.parse_args(["demo", "--waypoints", "3"]).tour_points == 3
