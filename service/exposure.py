"""Who can reach the service: the check ``pvtflow serve`` makes on its zenoh config before it opens anything.

A service that anyone on a network can ask to ``execute`` moves a machine. So a zenoh config that
reaches beyond this host must also authenticate every session and control access, the way the
shipped ``configs/zenoh/access-control.json5`` does (``transport.auth.usrpwd`` with a dictionary,
``access_control.enabled`` with ``default_permission: "deny"``), or the user must say
``--allow-unauthenticated``. The decision is made from the config alone: no socket is opened, no
name resolved.

Beyond this host means: a ``listen`` or ``connect`` endpoint whose address is not a loopback address
(``127.0.0.0/8``, ``::1``, ``localhost``; a host name may resolve anywhere, so it counts as beyond), a
peer or router that names no ``listen`` endpoint (zenoh then listens on every interface:
``tcp/[::]:0`` for a peer), and multicast scouting (zenoh's default unless the config turns it off:
the session answers and joins whoever scouts on the LAN). Unix sockets and pipes stay on the host.
"""

from __future__ import annotations

import ipaddress
import json
from dataclasses import dataclass

import zenoh

from pvtflow.configs import ZENOH_DIR
from pvtflow.service.program_fit import shown_path
from pvtflow.service.server import config_endpoints, config_mode

LOCAL_PROTOCOLS = frozenset({"unixsock-stream", "unixpipe"})  # not reachable from another host
DEFAULT_SCOUTING_ADDRESS = "224.0.0.224:7446"  # zenoh's multicast scouting group
ACCESS_CONTROL_EXAMPLE = ZENOH_DIR / "access-control.json5"


@dataclass(frozen=True)
class Exposure:
    """What a zenoh config opens beyond this host, and whether it keeps strangers out."""

    reachable: tuple[str, ...]  # each with why, e.g. "listen tcp/0.0.0.0:7447"
    authenticated: bool  # transport.auth.usrpwd with a dictionary: sessions must log in
    access_controlled: bool  # access_control enabled, default deny

    @property
    def protected(self) -> bool:
        return self.authenticated and self.access_controlled

    @property
    def open(self) -> bool:
        """Reachable from a network by anyone: ``pvtflow serve`` refuses it without --allow-unauthenticated."""
        return bool(self.reachable) and not self.protected

    def refusal(self, source: str) -> str:
        """The one-line refusal: what is open, what is missing, the two ways out."""
        missing = [
            what
            for what, ok in (
                ("authentication (transport.auth.usrpwd with a dictionary_file)", self.authenticated),
                ('access control (access_control.enabled, default_permission "deny")', self.access_controlled),
            )
            if not ok
        ]
        return (
            f"{source} reaches beyond this host ({', '.join(self.reachable)}) without {' and '.join(missing)}: "
            f"anyone who reaches it could execute motions. Enable both as {shown_path(ACCESS_CONTROL_EXAMPLE)} "
            "does, keep the endpoints on loopback, or pass --allow-unauthenticated"
        )


def is_local_endpoint(endpoint: str) -> bool:
    """A zenoh locator (``proto/address[?metadata][#config]``) that only this host can reach."""
    locator = endpoint.split("?", 1)[0].split("#", 1)[0]
    protocol, _, address = locator.partition("/")
    if protocol in LOCAL_PROTOCOLS:
        return True
    host = address.rsplit(":", 1)[0] if ":" in address else address
    host = host.strip("[]")
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a host name (resolves anywhere) or no address: beyond this host
        return False


def exposure(config: zenoh.Config) -> Exposure:
    """What ``config`` (with zenoh's defaults for what it leaves out) opens beyond this host."""
    mode = config_mode(config)
    reachable: list[str] = []
    listen = config_endpoints(config, "listen")
    reachable += [f"listen {e}" for e in listen if not is_local_endpoint(e)]
    if not listen and mode != "client":
        reachable.append(f"listen on every interface (zenoh's default for a {mode} without listen endpoints)")
    reachable += [f"connect {e}" for e in config_endpoints(config, "connect") if not is_local_endpoint(e)]
    if _get(config, "scouting/multicast/enabled") is not False:  # null: zenoh's default, on
        address = _get(config, "scouting/multicast/address") or DEFAULT_SCOUTING_ADDRESS
        reachable.append(f"multicast scouting udp/{address}")
    usrpwd = _get(config, "transport/auth/usrpwd")
    authenticated = isinstance(usrpwd, dict) and bool(usrpwd.get("dictionary_file"))
    access_controlled = _get(config, "access_control/enabled") is True and (
        _get(config, "access_control/default_permission") in (None, "deny")
    )
    return Exposure(tuple(reachable), authenticated, access_controlled)


def _get(config: zenoh.Config, key: str) -> object:
    """A config value as JSON (None where the config and zenoh's defaults have none)."""
    try:
        return json.loads(config.get_json(key))
    except Exception:  # a key this zenoh does not know
        return None
