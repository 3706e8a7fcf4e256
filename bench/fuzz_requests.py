"""10 000 generated bad requests to a running service over zenoh: every one answered with an error.

A pvtflow service for the arm6 cell (6 simulated EPOS2 drives, lockstep SYNC) behind a zenoh peer on
a free 127.0.0.1 port; a client session sends ``--count`` bad requests drawn (seeded) from every
class the service must refuse: not JSON, not an object, unknown fields, wrong types, wrong joint
counts, NaN / Infinity / 1e999, targets outside the joint limits, unknown joints, unknown plan
ids, oversized payloads and waypoint lists, bad programs (broken structure, a drive limit broken,
another cell's drives), bad status / stop / recover fields.

Counted: replies that are errors (must be all), error codes, ``internal_error`` replies (crashes
caught: must be 0), requests without a reply (must be 0), and afterwards: the service still
answers status, no drive got a record, the journal holds no motion (0 motions started).
Exit 0 when all of that holds.

Run:  python bench/fuzz_requests.py [--count 10000] [--seed 1]
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import random
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pvtflow.axes.canbus.clock import Clock
from pvtflow.axes.canbus.collector import freeze_startup_objects
from pvtflow.planner.plan import PlanInput
from pvtflow.service.api import MAX_REQUEST_BYTES, MAX_WAYPOINTS
from pvtflow.service.config import load_cell_config
from pvtflow.service.demo_cmd import free_port
from pvtflow.service.motion import MotionService
from pvtflow.service.request_cmd import Client
from pvtflow.service.server import Server, peer_config

Request = tuple[str, bytes]


class BadRequests:
    """Seeded generator of requests that must all be refused (each class returns op + payload)."""

    def __init__(
        self,
        rng: random.Random,
        joint_names: tuple[str, ...],
        lower: list[float],
        upper: list[float],
        program: dict[str, Any],
        other_program: dict[str, Any],
    ) -> None:
        self.rng = rng
        self.names = joint_names
        self.dof = len(joint_names)
        self.lower, self.upper = lower, upper
        self.program = program
        self.other_program = other_program
        self.classes: dict[str, Callable[[], Request]] = {
            "not_json": self.not_json,
            "not_object": self.not_object,
            "unknown_field": self.unknown_field,
            "wrong_type": self.wrong_type,
            "wrong_joint_count": self.wrong_joint_count,
            "not_finite": self.not_finite,
            "out_of_limits": self.out_of_limits,
            "unknown_joint": self.unknown_joint,
            "unknown_plan": self.unknown_plan,
            "too_many_waypoints": self.too_many_waypoints,
            "bad_program": self.bad_program,
            "bad_fields": self.bad_fields,
        }
        self.rare = {"oversized": self.oversized}

    def draw(self) -> tuple[str, str, bytes]:
        if self.rng.random() < 0.002:
            name = "oversized"
            op, payload = self.rare[name]()
        else:
            name = self.rng.choice(sorted(self.classes))
            op, payload = self.classes[name]()
        return name, op, payload

    # --- helpers -------------------------------------------------------------------------------
    def q(self) -> list[float]:
        return [self.rng.uniform(lo * 0.5, hi * 0.5) for lo, hi in zip(self.lower, self.upper, strict=True)]

    def junk(self, depth: int = 0) -> Any:
        kinds = ["int", "float", "str", "bool", "null"] + (["list", "dict"] if depth < 3 else [])
        k = self.rng.choice(kinds)
        if k == "int":
            return self.rng.randint(-(10**12), 10**12)
        if k == "float":
            return self.rng.uniform(-1e6, 1e6)
        if k == "str":
            return "".join(self.rng.choice("abcxyz_-/*$?#é ") for _ in range(self.rng.randint(0, 12)))
        if k == "bool":
            return self.rng.random() < 0.5
        if k == "null":
            return None
        if k == "list":
            return [self.junk(depth + 1) for _ in range(self.rng.randint(0, 4))]
        return {self.junk_key(): self.junk(depth + 1) for _ in range(self.rng.randint(0, 3))}

    def junk_key(self) -> str:
        return "".join(self.rng.choice("abcdefghijklmnopqrstuvwxyz_") for _ in range(self.rng.randint(1, 10)))

    @staticmethod
    def enc(value: Any) -> bytes:
        return json.dumps(value).encode()

    # --- classes -------------------------------------------------------------------------------
    def not_json(self) -> Request:
        op = self.rng.choice(["plan", "validate", "execute", "stop", "status", "recover"])
        choice = self.rng.randrange(4)
        if choice == 0:  # random bytes
            data = bytes(self.rng.randrange(256) for _ in range(self.rng.randint(1, 80)))
            try:
                json.loads(data)
                data = b"{" + data
            except ValueError:
                pass
            return op, data
        if choice == 1:  # a valid request cut short
            text = self.enc({"waypoints": [self.q(), self.q()]})
            return op, text[: self.rng.randint(1, len(text) - 1)]
        if choice == 2:  # Python / JSON5 syntax
            return op, self.rng.choice(
                [
                    b"{'target': [0]}",
                    b"{target: [0]}",
                    b'{"a": 1,}',
                    b"[1, 2",
                    b"None",
                    b"\t",
                    b" ",
                    b"\x00",
                    b'{"a": 01}',
                    b"0x10",
                ]
            )
        return op, '{"label": "\udcff"}'.encode("utf-8", "surrogatepass")  # not UTF-8

    def not_object(self) -> Request:
        op = self.rng.choice(["plan", "validate", "execute", "stop", "status", "recover"])
        value = self.junk()
        while isinstance(value, dict):
            value = self.junk()
        return op, self.enc(value)

    def unknown_field(self) -> Request:
        op = self.rng.choice(["plan", "validate", "execute", "stop", "status", "recover"])
        base: dict[str, Any] = {
            "plan": {"target": self.q()},
            "validate": {"plan_id": "p-1"},
            "execute": {"plan_id": "p-1"},
            "stop": {},
            "status": {},
            "recover": {},
        }[op]
        key = self.junk_key()
        while key in (
            "target",
            "waypoints",
            "joint_names",
            "start",
            "tolerance_qc",
            "label",
            "include_program",
            "plan_id",
            "program",
            "wait",
            "reason",
            "recent",
        ):
            key = self.junk_key() + "_x"
        return op, self.enc({**base, key: self.junk()})

    def wrong_type(self) -> Request:
        field = self.rng.choice(
            ["waypoints", "target", "joint_names", "start", "tolerance_qc", "label", "include_program"]
        )
        bad: Any = self.junk()
        if field == "waypoints":
            bad = self.rng.choice(
                [
                    self.junk_key(),
                    5,
                    {"a": 1},
                    [self.junk_key()],
                    [[self.junk_key()] * self.dof],
                    [[True] * self.dof],
                    [None],
                    [],
                ]
            )
        elif field == "target":
            bad = self.rng.choice(
                [
                    self.junk_key(),
                    [str(x) for x in self.q()],
                    [None] * self.dof,
                    {"q": 1},
                    [[0.0] * self.dof],
                    [False] * self.dof,
                ]
            )
        elif field in ("start",):
            bad = self.rng.choice([self.junk_key(), 1, None, ["current"]])
        elif field == "tolerance_qc":
            bad = self.rng.choice([0, -1, 0.1, 10**6, "1", None, [1]])
        elif field == "include_program":
            bad = self.rng.choice([1, "yes", None, []])
        elif field == "label":
            bad = self.rng.choice([1, None, ["x"], "x" * 500])
        elif field == "joint_names":
            bad = self.rng.choice(["joint_1", [1, 2, 3, 4, 5, 6], [], None])
        body = {"target": self.q()} if field not in ("waypoints", "target") else {}
        body[field] = bad
        return "plan", self.enc(body)

    def wrong_joint_count(self) -> Request:
        n = self.rng.choice([k for k in range(0, 13) if k != self.dof])
        vec = [self.rng.uniform(-0.2, 0.2) for _ in range(n)]
        if self.rng.random() < 0.5:
            return "plan", self.enc({"target": vec})
        rows = [self.q() for _ in range(self.rng.randint(1, 5))]
        rows.insert(self.rng.randrange(len(rows) + 1), vec)
        return "plan", self.enc({"waypoints": rows})

    def not_finite(self) -> Request:
        vec = [json.dumps(x) for x in self.q()]
        vec[self.rng.randrange(self.dof)] = self.rng.choice(["NaN", "Infinity", "-Infinity", "1e999", "-1e400"])
        text = "[" + ", ".join(vec) + "]"
        if self.rng.random() < 0.5:
            return "plan", f'{{"target": {text}}}'.encode()
        return "plan", f'{{"waypoints": [{json.dumps(self.q())}, {text}]}}'.encode()

    def out_of_limits(self) -> Request:
        vec = self.q()
        j = self.rng.randrange(self.dof)
        span = self.upper[j] - self.lower[j]
        vec[j] = (
            self.upper[j] + self.rng.uniform(1e-6, span)
            if self.rng.random() < 0.5
            else self.lower[j] - self.rng.uniform(1e-6, span)
        )
        if self.rng.random() < 0.5:
            return "plan", self.enc({"target": vec})
        return "plan", self.enc(
            {"waypoints": [self.q(), vec, self.q()], "start": self.rng.choice(["first", "current"])}
        )

    def unknown_joint(self) -> Request:
        names = list(self.names)
        k = self.rng.randrange(3)
        if k == 0:
            names[self.rng.randrange(self.dof)] = self.junk_key()
        elif k == 1:
            names[0] = names[1]
        else:
            names = [*names[:-1], names[0]]
        return "plan", self.enc({"target": self.q(), "joint_names": names})

    def unknown_plan(self) -> Request:
        pid = "p-" + "".join(self.rng.choice("0123456789abcdef") for _ in range(16))
        op = self.rng.choice(["execute", "validate"])
        body: dict[str, Any] = {"plan_id": pid}
        if op == "execute" and self.rng.random() < 0.3:
            body["wait"] = True
        return op, self.enc(body)

    def too_many_waypoints(self) -> Request:
        return "plan", self.enc({"waypoints": [self.q() for _ in range(MAX_WAYPOINTS + 1 + self.rng.randrange(50))]})

    def oversized(self) -> Request:
        op = self.rng.choice(["plan", "execute", "status"])
        return op, b'{"label": "' + b"a" * (MAX_REQUEST_BYTES + self.rng.randrange(1000)) + b'"}'

    def bad_program(self) -> Request:
        prog = copy.deepcopy(self.program)
        k = self.rng.randrange(6)
        axis = self.rng.randrange(len(prog["axes"]))
        if k == 0:  # a record faster than 0x607F allows
            prog["axes"][axis]["records"][1][1] = self.rng.choice([1, -1]) * self.rng.randint(10**6, 8 * 10**6)
        elif k == 1:  # a structural error
            del prog["axes"][axis][self.rng.choice(["records", "node_id", "profile", "limits"])]
        elif k == 2:  # another cell's program
            prog = copy.deepcopy(self.other_program)
        elif k == 3:  # out-of-range or non-integer records
            prog["axes"][axis]["records"][1][self.rng.randrange(3)] = self.rng.choice([2**40, 1.5, "x", None])
        elif k == 4:  # a node that is not in the cell
            prog["axes"][axis]["node_id"] = 100 + self.rng.randrange(27)
        else:  # jumps (a position step in 1 ms)
            prog["axes"][axis]["records"][1] = [prog["axes"][axis]["records"][0][0] + 100000, 0, 1]
        if k == 2:  # validate answers a foreign program with a verdict (not an error): execute only
            return "execute", self.enc({"program": prog})
        if k in (1, 3):  # unreadable programs: refused by both
            return self.rng.choice(["execute", "validate"]), self.enc({"program": prog})
        return "execute", self.enc({"program": prog})

    def bad_fields(self) -> Request:
        k = self.rng.randrange(5)
        if k == 0:
            return "status", self.enc({"recent": self.rng.choice([-1, 101, 10**9, "5", 2.5, None, []])})
        if k == 1:
            return "stop", self.enc({"reason": self.rng.choice([1, None, ["x"], {"a": 1}, "x" * 300])})
        if k == 2:
            return "recover", self.enc({self.junk_key(): self.junk()})
        if k == 3:
            return "execute", self.enc({"plan_id": self.rng.choice(["", "a" * 65, "../x", "p 1", 7, None])})
        return "execute", self.enc({"plan_id": "p-1", "program": {}})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--count", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for each reply")
    args = parser.parse_args(argv)

    cell = load_cell_config(None)
    gantry = load_cell_config(Path(__file__).resolve().parent.parent / "configs" / "cells" / "gantry3.yaml")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    service = MotionService(cell, journal_dir=tempfile.mkdtemp(prefix="pvtflow-fuzz-"), clock=Clock.LOCKSTEP).open()
    freeze_startup_objects()  # as pvtflow serve does once its service is open
    server = Server(service, peer_config(listen=[endpoint])).start()
    client = Client(connect=endpoint)
    codes: Counter[str] = Counter()
    by_class: Counter[str] = Counter()
    not_errors: list[tuple[str, str, bytes, Any]] = []
    no_reply = 0
    try:
        from pvtflow.service.cell_planner import plan_cell_program

        program = plan_cell_program(cell, PlanInput([[0.0] * 6, [0.2, -0.1, 0.2, -0.1, 0.2, -0.1]])).program
        other = plan_cell_program(gantry, PlanInput([[0.0, 0.0, 0.0], [0.1, 0.1, -0.05]])).program
        assert program is not None and other is not None
        lim = service.limits
        gen = BadRequests(
            random.Random(args.seed),
            service.joint_names,
            list(map(float, lim.lower)),
            list(map(float, lim.upper)),
            program.to_json(),
            other.to_json(),
        )
        t0 = time.perf_counter()
        for _ in range(args.count):
            name, op, payload = gen.draw()
            by_class[name] += 1
            replies = client.replies(cell.name, op, payload, args.timeout)
            if not replies:
                no_reply += 1
                continue
            reply = replies[0]
            if reply.ok:
                not_errors.append((name, op, payload[:200], reply.data))
            else:
                codes[reply.error_code or "?"] += 1
        elapsed = time.perf_counter() - t0
        status = client.request(cell.name, "status", {"recent": 10})
        alive = status.ok and status.data["state"] == "idle"
        records = sum(d.records_received for d in service.sim)
        motions = len(service.journal.recent(100))
    finally:
        client.close()
        server.close()
        service.close()

    crashes = codes.get("internal_error", 0)
    print(f"command: python bench/fuzz_requests.py --count {args.count} --seed {args.seed}")
    print(
        f"cell {cell.name} (6 simulated EPOS2 axes), zenoh peer {endpoint}; {os.cpu_count()} CPU(s); "
        f"{args.count} requests in {elapsed:.1f} s ({1000 * elapsed / args.count:.2f} ms each)"
    )
    print("requests by class: " + ", ".join(f"{k} {v}" for k, v in sorted(by_class.items())))
    print("error replies by code: " + ", ".join(f"{k} {v}" for k, v in sorted(codes.items())))
    print(
        f"answered with an error: {sum(codes.values())}/{args.count}; not an error: {len(not_errors)}; "
        f"no reply: {no_reply}; internal errors (crashes caught): {crashes}"
    )
    print(f"after: service answers status: {alive}; records sent to drives: {records}; motions started: {motions}")
    for item in not_errors[:5]:
        print(f"  NOT REFUSED: {item}")
    ok = not not_errors and no_reply == 0 and crashes == 0 and alive and records == 0 and motions == 0
    print("RESULT: " + ("every bad request refused, 0 crashes, 0 motions started" if ok else "FAILED"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
