"""``pvtflow demo --sequence [FILE]``: a motion sequence run twice through zenoh, the second cycle queued.

The demo's service and client (``service/demo_cmd.py``) with a sequence instead of the tour: the file (default:
the shipped arm6 pick and place, configs/sequences/) is planned as it says, its second cycle from where the
first ends; the first runs with ``approach`` (the axes move to its start first), the second is executed with
``queue`` while the first runs, so it runs on from the first's last record with no stop in between. The
items are announced as they begin (``item_started``); at the end, the SYNC the second cycle began on
against the SYNC after the first one's last record, and a plot of both cycles' telemetry.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

from pvtflow.service.config import CONFIG_DIR
from pvtflow.service.request_cmd import Client
from pvtflow.service.waypoints import WaypointError, load_sequence

PROG = "pvtflow demo"
PICK_AND_PLACE = CONFIG_DIR / "sequences" / "arm6-pick-and-place.yaml"


def _refused(what: str, reply: Any) -> bool:
    if reply.ok:
        return False
    err = reply.data["error"]
    print(f"{PROG}: {what} refused: {err['code']}: {err['message']}", file=sys.stderr)
    return True


def run_sequence(
    client: Client, name: str, joint_names: list[str], path: Path, follower: Any, plot: Path, period_ms: float
) -> bool:
    """Plan the sequence twice (the second from the first's end), run the first, queue the second: whether
    both finished with the second begun on the SYNC after the first's last record."""
    try:
        seq = load_sequence(path, joint_names)
    except WaypointError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return False
    start: Any = "current" if seq.start is None else [float(x) for x in seq.start]
    first = client.request(name, "plan", {"sequence": seq.items, "start": start, "label": f"{path.stem} 1"})
    if _refused("plan", first):
        return False
    again = {"sequence": seq.items, "start": first.data["end"], "label": f"{path.stem} 2"}
    second = client.request(name, "plan", again)
    if _refused("plan of the second cycle", second):
        return False
    for p in (first.data, second.data):
        print(f"  plan {p['plan_id']} ({p['label']}): {len(seq.items)} items, {p['duration_s']:.3f} s, validated")
    ex = client.request(name, "execute", {"plan_id": first.data["plan_id"], "approach": True}, timeout=120.0)
    if _refused("execute", ex):
        return False
    if ex.data.get("approach") is not None:
        print(f"  approach {ex.data['approach']['motion_id']} moved the axes to the sequence's start")
    follower.follow(ex.data["motion_id"])
    queued = client.request(name, "execute", {"plan_id": second.data["plan_id"], "queue": True})
    if _refused("queued execute", queued):
        return False
    ids = [ex.data["motion_id"], queued.data["motion_id"]]
    print(f"  motion {ids[0]} started on SYNC {ex.data['start_sync']}; {ids[1]} queued after it")
    follower.ended.wait(max(30.0, 10 * first.data["duration_s"]))
    follower.follow(ids[1])
    if not follower.ended.wait(max(30.0, 10 * second.data["duration_s"])):
        print(f"\n{PROG}: the queued motion did not end in time: stopping", file=sys.stderr)
        client.request(name, "stop", {"reason": "demo timeout"})
        return False
    follower.end_line()
    for motion_id in ids:
        items = [
            e["item"] for e in follower.events if e.get("kind") == "item_started" and e.get("motion_id") == motion_id
        ]
        ended = next(
            (e for e in follower.events if e.get("kind") == "motion_ended" and e.get("motion_id") == motion_id), {}
        )
        said = ", ".join(f"{i['index']} {i['label'] or ''}".strip() for i in items)
        print(f"  {motion_id}: items {said}; {ended.get('message', 'no end')}")
    status = client.request(name, "status", {"recent": 2})
    if _refused("status", status):
        return False
    begun = (status.data["motion"] or {}).get("start_sync")
    after = ex.data["start_sync"] + math.ceil(first.data["duration_s"] * 1000.0 / period_ms)
    standstill = None if begun is None else begun - after
    print(
        f"  the queued cycle began on SYNC {begun}, the SYNC after the first one's last record is {after}: "
        f"{standstill} SYNC periods of standstill between them beyond the plans' own"
    )
    tel = follower.by_motion.get(ids[0], []) + [
        {**d, "elapsed_ms": d["elapsed_ms"] + 1000.0 * first.data["duration_s"]}
        for d in follower.by_motion.get(ids[1], [])
    ]
    if tel:
        from pvtflow.service.demo_cmd import write_plot

        write_plot(plot, tel, joint_names, f"pvtflow demo: {path.name} twice, the second cycle queued ({ids[1]})")
        print(f"  plot: {plot} ({len(tel)} telemetry samples of both cycles)")
    outcomes = [status.data["recent"][k]["outcome"] for k in range(min(2, len(status.data["recent"])))]
    return standstill == 0 and all(o is not None and o["result"] == "finished" for o in outcomes)
