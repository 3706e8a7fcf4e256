"""``pvtflow report RUN.mcap [--plot OUT.png] [--json]``: what a recorded run did (service/recording).

The figures come from the recording alone: its duration (first to last message, bus clock), the
worst following error per axis (planned minus actual at each SYNC of the run, counts), the SYNC
intervals (mean, worst deviation from the cell's period, p99) and every fault and error event. A
file cut short (a process killed mid-motion) is reported up to its last chunk and says so. Exit
codes: 0 reported, 2 unreadable file or plot.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

import numpy as np

from pvtflow.service.cli_options import add_json
from pvtflow.service.recording import Recording, RecordingError, read_recording
from pvtflow.service.recording.channels import ERROR

PROG = "pvtflow report"
EXIT_OK, EXIT_UNREADABLE = 0, 2


def add_parser(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "report",
        help="summarize a recorded run (pvtflow execute/home --record, serve --record): following error, SYNC, faults",
        description="Duration, worst following error per axis, SYNC jitter and faults of an MCAP recording; "
        "--plot draws planned against actual, following error and buffers per axis.",
    )
    p.add_argument("recording", metavar="RUN.mcap", help="a recording written by pvtflow")
    p.add_argument("--plot", metavar="OUT.png", help="write planned vs actual, following error and buffers per axis")
    add_json(p)
    p.set_defaults(run=run)


def summarize(rec: Recording) -> dict[str, Any]:
    meta = rec.metadata.get("pvtflow", {})
    joints = [j for j in meta.get("joints", "").split(",") if j]
    period = float(meta.get("sync_period_ms", "nan"))
    times = [m.log_time_ns for m in rec.messages]
    axes: dict[str, Any] = {}
    for joint in joints:
        samples = [m.data for m in rec.topic(f"/axis/{joint}/actual")]
        errors = [(s["following_error_qc"], s) for s in samples if s["following_error_qc"] is not None]
        worst = max(errors, key=lambda e: abs(e[0]), default=None)
        planned = rec.topic(f"/axis/{joint}/planned")
        axes[joint] = {
            "syncs": len(samples),
            "planned_samples": len(planned),
            "worst_following_error_qc": None if worst is None else worst[0],
            "worst_at_elapsed_ms": None if worst is None else worst[1]["elapsed_ms"],
        }
    intervals = np.array([m.data["interval_ms"] for m in rec.topic("/sync") if m.data["interval_ms"] is not None])
    sync: dict[str, Any] = {"period_ms": period, "count": len(rec.topic("/sync"))}
    if len(intervals):
        deviation = np.abs(intervals - period)
        sync.update(
            mean_interval_ms=float(intervals.mean()),
            max_interval_ms=float(intervals.max()),
            jitter_max_ms=float(deviation.max()),
            jitter_p99_ms=float(np.percentile(deviation, 99)),
        )
    faults = [m.data for m in rec.topic("/faults")]
    errors = [m.data for m in rec.topic("/events") if m.data["level"] >= ERROR]
    outcome = json.loads(rec.metadata["outcome"]["json"]) if "outcome" in rec.metadata else None
    return {
        "cell": meta.get("cell"),
        "kind": meta.get("kind"),
        "complete": rec.complete,
        "messages": len(rec.messages),
        "duration_s": (max(times) - min(times)) / 1e9 if times else 0.0,
        "result": outcome.get("result") if isinstance(outcome, dict) else None,
        "axes": axes,
        "sync": sync,
        "faults": faults,
        "error_events": [f"{e['name']}: {e['message']}" for e in errors],
    }


def describe(report: dict[str, Any]) -> str:
    state = "complete" if report["complete"] else "cut short (read up to its last chunk)"
    lines = [
        f"{report['kind'] or 'run'} on cell {report['cell']}: {report['duration_s']:.3f} s, "
        f"{report['messages']} messages, {state}" + (f", result {report['result']}" if report["result"] else "")
    ]
    for joint, a in report["axes"].items():
        worst = a["worst_following_error_qc"]
        text = "-" if worst is None else f"{worst:+.1f} qc at {a['worst_at_elapsed_ms']:.0f} ms"
        lines.append(f"  {joint}: worst following error {text} ({a['syncs']} SYNCs)")
    s = report["sync"]
    if "mean_interval_ms" in s:
        lines.append(
            f"  SYNC: {s['count']} frames, period {s['period_ms']:g} ms, mean interval {s['mean_interval_ms']:.3f} ms, "
            f"jitter p99 {s['jitter_p99_ms']:.3f} ms, max {s['jitter_max_ms']:.3f} ms"
        )
    faults = report["faults"]
    lines.append(f"  faults: {len(faults)}" + "".join(f"\n    {f['kind']}: {f['message']}" for f in faults))
    return "\n".join(lines)


def plot(rec: Recording, joints: list[str], out: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, grid = plt.subplots(len(joints), 3, figsize=(15, 2.6 * max(1, len(joints))), squeeze=False)
    t0 = min((m.log_time_ns for m in rec.messages), default=0)
    buffers = rec.topic("/buffers")
    for row, joint in zip(grid, joints, strict=True):
        planned = rec.topic(f"/axis/{joint}/planned")
        actual = [m for m in rec.topic(f"/axis/{joint}/actual") if m.data["position_qc"] is not None]
        row[0].plot(
            [(m.log_time_ns - t0) / 1e9 for m in planned], [m.data["position_qc"] for m in planned], label="planned"
        )
        row[0].plot(
            [(m.log_time_ns - t0) / 1e9 for m in actual],
            [m.data["position_qc"] for m in actual],
            ".",
            markersize=2,
            label="actual",
        )
        row[0].set_ylabel(f"{joint} [qc]")
        row[0].legend(loc="best", fontsize="small")
        err = [m for m in actual if m.data["following_error_qc"] is not None]
        row[1].plot([(m.log_time_ns - t0) / 1e9 for m in err], [m.data["following_error_qc"] for m in err])
        row[1].set_ylabel("following error [qc]")
        k = joints.index(joint)
        levels = [(m.log_time_ns, m.data["levels"][k]) for m in buffers if m.data["levels"][k] is not None]
        row[2].step([(t - t0) / 1e9 for t, _ in levels], [lv for _, lv in levels], where="post")
        row[2].set_ylabel("records buffered")
    for ax in grid[-1]:
        ax.set_xlabel("bus time [s]")
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    try:
        rec = read_recording(args.recording)
    except RecordingError as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return EXIT_UNREADABLE
    if "pvtflow" not in rec.metadata:
        print(f"{PROG}: {args.recording}: not a pvtflow recording (no pvtflow metadata)", file=sys.stderr)
        return EXIT_UNREADABLE
    report = summarize(rec)
    if args.plot:
        try:
            plot(rec, list(report["axes"]), args.plot)
        except (OSError, ValueError) as exc:
            print(f"{PROG}: cannot write the plot {args.plot}: {exc}", file=sys.stderr)
            return EXIT_UNREADABLE
    print(json.dumps(report, indent=2) if args.json else describe(report), flush=True)
    return EXIT_OK
