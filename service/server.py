"""The zenoh face of one cell: queryables, publications and the liveliness token (DESIGN section 7).

``pvtflow/<cell>/{plan,validate,execute,stop,status,recover,home}`` are queryables (JSON in, JSON out,
errors as ``reply_err`` with ``{"error": {"code", "message", "details"}}``);
``pvtflow/<cell>/{state,telemetry,events}`` are publications; ``pvtflow/<cell>/alive`` is the
liveliness token. The session is a peer on explicit endpoints with multicast and gossip scouting
off (configs/zenoh/service.json5), unless the user gives a zenoh JSON5 file, used as is.

Queries are handed from zenoh's callback threads to worker pools at once, so a long plan never
delays a stop: planning (plan, validate) has its own workers, motion commands (execute, stop,
status, recover, home) theirs. Publications go through a queue and one publisher thread, so the bus
threads that produce telemetry never wait on the network.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
import traceback
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import zenoh

from pvtflow.configs import ZENOH_DIR as ZENOH_CONFIG_DIR
from pvtflow.service.api import (
    LIVELINESS,
    PUBLICATIONS,
    QUERYABLES,
    ApiError,
    ErrorCode,
    check_cell_name,
    dumps,
    key,
    parse_execute,
    parse_home,
    parse_override,
    parse_pause,
    parse_payload,
    parse_plan,
    parse_recover,
    parse_resume,
    parse_status,
    parse_stop,
    parse_validate,
)
from pvtflow.service.motion import MotionService, ServiceEventKind

log = logging.getLogger("pvtflow.server")

DEFAULT_SERVICE_CONFIG = ZENOH_CONFIG_DIR / "service.json5"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
JSON = zenoh.Encoding.APPLICATION_JSON
PLANNING_OPS = frozenset({"plan", "validate"})


def zenoh_message(exc: BaseException) -> str:
    """zenoh's error text without the Rust source location it appends."""
    return str(exc).split(" at /", 1)[0].strip()


class ZenohConfigError(ValueError):
    """A zenoh configuration file that cannot be read or used."""


def load_zenoh_config(path: str | Path | None = None) -> zenoh.Config:
    """The user's zenoh JSON5 file as is, or pvtflow's default service config (peer, loopback, no scouting)."""
    file = Path(path) if path is not None else DEFAULT_SERVICE_CONFIG
    if not file.is_file():
        raise ZenohConfigError(f"{file}: {'is a directory' if file.is_dir() else 'file not found'}")
    try:
        return zenoh.Config.from_file(str(file))
    except Exception as exc:  # zenoh raises ZError (or a parse error) with the JSON5 location
        raise ZenohConfigError(f"{file}: not a usable zenoh configuration: {zenoh_message(exc)}") from None


def peer_config(listen: list[str] | tuple[str, ...] = (), connect: list[str] | tuple[str, ...] = ()) -> zenoh.Config:
    """A peer on explicit endpoints, multicast and gossip scouting off (what tests and clients use)."""
    return zenoh.Config.from_json5(
        json.dumps(
            {
                "mode": "peer",
                "listen": {"endpoints": list(listen)},
                "connect": {"endpoints": list(connect)},
                "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
            }
        )
    )


def client_config(connect: list[str] | tuple[str, ...] = (DEFAULT_ENDPOINT,)) -> zenoh.Config:
    """A client session on explicit endpoints (a service's peer, or a router), scouting off."""
    return zenoh.Config.from_json5(
        json.dumps(
            {
                "mode": "client",
                "connect": {"endpoints": list(connect)},
                "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
            }
        )
    )


def config_endpoints(config: zenoh.Config, which: str = "listen") -> list[str]:
    """The endpoints a config lists under ``listen`` or ``connect`` (empty when it names none); the
    per-mode form ``{"router": [...], "peer": [...]}`` (zenoh's own default) gives the config's mode's."""
    try:
        value = config.get_json(f"{which}/endpoints")
        if isinstance(value, str):
            value = json.loads(value)
    except Exception:
        return []
    if isinstance(value, dict):
        value = value.get(config_mode(config), [])
    return [str(v) for v in value or []]


def config_mode(config: zenoh.Config) -> str:
    """The session's mode: ``peer`` (zenoh's default), ``client`` or ``router``."""
    try:
        mode = json.loads(config.get_json("mode"))
    except Exception:
        return "peer"
    return mode if isinstance(mode, str) else "peer"


class Server:
    """One cell's MotionService on a zenoh session."""

    def __init__(
        self,
        service: MotionService,
        config: zenoh.Config | None = None,
        *,
        idle_telemetry_s: float = 1.0,
        workers: int = 8,
    ) -> None:
        self.service = service
        self.cell = check_cell_name(service.cell.name)
        self.config = config if config is not None else load_zenoh_config(None)
        self.idle_telemetry_s = idle_telemetry_s
        self.session: zenoh.Session | None = None
        self._queryables: list[Any] = []
        self._publishers: dict[str, Any] = {}
        self._token: Any = None
        self._planning = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"pvtflow-plan-{self.cell}")
        self._control = ThreadPoolExecutor(max_workers=workers, thread_name_prefix=f"pvtflow-ctl-{self.cell}")
        self._outbox: queue.Queue[tuple[str, dict[str, Any]] | None] = queue.Queue(maxsize=20000)
        self._stopping = threading.Event()
        self._threads: list[threading.Thread] = []
        self.dropped_publications = 0
        self.handlers: dict[str, Callable[[Any], dict[str, Any]]] = {
            "plan": lambda d: service.plan(parse_plan(d, service.joint_names, service.limits)),
            "validate": lambda d: service.validate(parse_validate(d)),
            "execute": lambda d: service.execute(parse_execute(d)),
            "stop": lambda d: service.stop(parse_stop(d)),
            "status": lambda d: service.status(parse_status(d)),
            "recover": lambda d: service.recover(parse_recover(d)),
            "home": lambda d: service.home(parse_home(d)),
            "pause": lambda d: service.pause(parse_pause(d)),
            "resume": lambda d: service.resume(parse_resume(d)),
            "override": lambda d: service.override(parse_override(d)),
        }

    # --- the pure part: payload in, (ok, JSON bytes) out -------------------------------------------
    def handle(self, op: str, payload: bytes | None, received: float | None = None) -> tuple[bool, bytes]:
        """Answer one request; never raises (a bug becomes an ``internal_error`` reply).

        ``received`` (time.perf_counter() when the query arrived): a plan reply's ``timing_ms``
        then gets ``service``, the time from the query's arrival to its reply being built (queue,
        parsing, planning, bookkeeping), so that a client can tell the service's time from the
        network's.
        """
        try:
            data = parse_payload(payload)
            out = self.handlers[op](data)
            if received is not None and op == "plan":
                service_ms = round((time.perf_counter() - received) * 1000.0, 3)
                out = {**out, "timing_ms": {**out["timing_ms"], "service": service_ms}}
            return True, dumps(out)
        except ApiError as exc:
            return False, exc.to_bytes()
        except Exception as exc:  # a bug must not take the service down
            log.error("internal error in %s: %s", op, traceback.format_exc())
            err = ApiError(ErrorCode.INTERNAL_ERROR, f"internal error while handling {op}: {type(exc).__name__}: {exc}")
            return False, err.to_bytes()

    # --- zenoh ---------------------------------------------------------------------------------
    def start(self) -> Server:
        self.session = zenoh.open(self.config)
        for topic in PUBLICATIONS:
            self._publishers[topic] = self.session.declare_publisher(key(self.cell, topic), encoding=JSON)
        self.service.publish = self._enqueue
        self._spawn(self._publish_loop, "publish")
        if self.idle_telemetry_s > 0:
            self._spawn(self._idle_telemetry_loop, "telemetry")
        for op in QUERYABLES:
            self._queryables.append(
                self.session.declare_queryable(key(self.cell, op), lambda query, op=op: self._on_query(op, query))
            )
        self._token = self.session.liveliness().declare_token(key(self.cell, LIVELINESS))
        self._enqueue(
            "events", self.service.event_payload(ServiceEventKind.SERVICE_STARTED, f"cell {self.cell} is being served")
        )
        return self

    def _spawn(self, target: Callable[[], None], name: str) -> None:
        t = threading.Thread(target=target, name=f"pvtflow-{name}-{self.cell}", daemon=True)
        t.start()
        self._threads.append(t)

    def _on_query(self, op: str, query: zenoh.Query) -> None:
        """zenoh callback thread: hand the query to a worker and return at once."""
        received = time.perf_counter()
        payload = query.payload.to_bytes() if query.payload is not None else None
        pool = self._planning if op in PLANNING_OPS else self._control
        try:
            pool.submit(self._answer, op, query, payload, received)
        except RuntimeError:  # shutting down
            query.reply_err(ApiError(ErrorCode.NOT_ALLOWED, "the service is shutting down").to_bytes(), encoding=JSON)
            query.drop()

    def _answer(self, op: str, query: zenoh.Query, payload: bytes | None, received: float) -> None:
        ok, body = self.handle(op, payload, received)
        try:
            if ok:
                query.reply(key(self.cell, op), body, encoding=JSON)
            else:
                query.reply_err(body, encoding=JSON)
        except Exception as exc:  # the querier went away (timeout): nothing to do
            log.warning("cannot reply to %s: %s", op, exc)
        finally:
            query.drop()

    def _enqueue(self, topic: str, payload: dict[str, Any]) -> None:
        try:
            self._outbox.put_nowait((topic, payload))
        except queue.Full:
            self.dropped_publications += 1

    def _publish_loop(self) -> None:
        while True:
            item = self._outbox.get()
            if item is None:
                return
            topic, payload = item
            try:
                self._publishers[topic].put(dumps(payload))
            except Exception as exc:
                log.warning("cannot publish %s: %s", topic, exc)

    def _idle_telemetry_loop(self) -> None:
        while not self._stopping.wait(self.idle_telemetry_s):
            if not self.service.running and self.service.group is not None:
                try:
                    self._enqueue("telemetry", self.service.telemetry_snapshot())
                except Exception as exc:
                    log.warning("idle telemetry: %s", exc)

    @property
    def listen_endpoints(self) -> list[str]:
        return config_endpoints(self.config, "listen")

    def close(self) -> None:
        """Stop answering, drop the liveliness token, flush the publications, close the session."""
        if self._stopping.is_set():
            return
        self._stopping.set()
        for q in self._queryables:
            q.undeclare()
        self._queryables.clear()
        if self._token is not None:
            self._token.undeclare()
            self._token = None
        self._planning.shutdown(wait=True, cancel_futures=True)
        self._control.shutdown(wait=True, cancel_futures=True)
        self._outbox.put(None)
        for t in self._threads:
            t.join(timeout=2.0)
        self._threads.clear()
        for p in self._publishers.values():
            p.undeclare()
        self._publishers.clear()
        if self.session is not None:
            self.session.close()
            self.session = None

    def __enter__(self) -> Server:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
