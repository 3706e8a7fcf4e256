"""The simulated wire: a python-can interface (``simwire``) that behaves like a classic CAN bus.

python-can's ``virtual`` interface carries any number of frames in no time; a real bus does not.
``can.Bus(interface="simwire", channel=..., bitrate=..., clock=..., sync_period=...)`` (entry
point ``can.interface``: ``axes.sim.wire.interface:SimWireBus``) opens one node on a shared
medium with these semantics:

* **Nodes.** Each bus opened on a channel is a node with its own transmit FIFO of ``txqueuelen``
  frames (default 10, SocketCAN's; the frame on the wire counts until its last bit). ``send()`` on
  a full FIFO raises ``can.CanOperationError`` with ``error_code`` ENOBUFS, as python-can's
  socketcan does; ``send(msg, timeout=T)`` with T > 0 first waits up to T for room.
* **Bit timing.** A frame occupies the bus for ``axes.canbus.frame_time.frame_bits(...) / bitrate``
  seconds (exact stuffing, interframe space included). Every other node receives it with
  ``msg.timestamp`` = the bus time its last bit left the wire. The sender sees its own frame only
  with ``receive_own_messages=True`` (then ``is_rx`` False), as on socketcan. Classic frames only.
  ``bus.accept_only(accepts)`` (in-process media): a live acceptance filter on the identifier, as
  a controller's or SocketCAN's CAN_RAW_FILTER: refused frames take their wire time but never reach
  the node's queue (the simulated drives pass what their canopen network subscribes to).
* **Clocks.** Chosen by the medium's creator (``clock="wall"|"lockstep"``); every opener of the
  channel must agree or pass None, else ``WireConfigError``. Same for ``bitrate`` (default
  1 Mbit/s) and ``sync_period``.

  - ``wall``: bus time is wall time, as epoch seconds (``time.time()`` when the medium started
    plus the ``time.monotonic()`` since: one time base for every process of the host). A thread
    (``wall.WallDriver``) delivers each frame when its last bit is due, in batches when it woke
    late (time stamps stay exact). Arbitration is exact: whenever the bus goes idle, among the
    FIFO heads queued by then the lowest identifier wins (base before extended for equal 11 bits,
    data before remote). A frame that reaches the medium late (a post from another process) but
    was queued no later than the start of the frame on the wire, not yet delivered, takes part in
    that frame's arbitration (``Medium._rearbitrate``); frames already delivered stay where they were.
  - ``lockstep``: bus time is virtual (seconds from 0) and advances with the SYNC (identifier
    0x80) period ``sync_period``. Frames are delivered inside ``send()``, stamped with their virtual
    end. Each node keeps a local time, the latest time stamp among the frames of other nodes its
    ``recv()`` returned (its own echoes do not count). A frame is enqueued at max(local time, the
    nominal time of the last SYNC on the wire); a SYNC at max(local time, previous SYNC's nominal
    time + sync_period), which becomes its nominal time (the first SYNC's is the sender's local
    time). A frame starts at max(enqueue time, end of its sender's previous frame, end of the last
    frame on the bus). With eager delivery, arbitration among frames pending at the same time
    cannot be honoured (the first ``send()`` takes the bus): the bus load (work conserving) and the
    lateness of a SYNC behind its own sender's FIFO are exact, the order among nodes is not. The
    FIFO bound is judged in virtual time: the sender's frames that end after the new frame's
    enqueue time are queued; ``txqueuelen`` of them already -> ENOBUFS. So a master that sends a
    SYNC and then a burst gets ENOBUFS on the 11th frame (the SYNC is in its FIFO too). A sender
    that waits (``send(msg, timeout=T)``) lets its FIFO drain in bus time: its frame goes out when
    a slot frees, if within T. An idle bus (no SYNC for ``medium.IDLE_S`` of wall time) follows the
    wall clock, so heartbeats and SDO exchanges between motions do not pile up at one instant.
    A wall-clock FIFO is judged in bus time: at a send, frames whose last bit has left by its time
    are out of it, whether or not the driver thread has woken yet to deliver them.
  - A cyclic send (``send_periodic``) on an in-process wall-clock medium is timed by the medium,
    as SocketCAN's broadcast manager times it: each frame queued at its due bus time, heard by
    its own node too; a client of a served medium asks for the same with ``cyclic_by_medium=True``.
  - A transmit schedule (``bus.send_at(msgs, due)``, wall clock, in-process or served): the frames
    enter the node's FIFO at bus time ``due``, as a cyclic frame at its due time (placed by it among the
    node's posts, arbitrated from it, dropped where the FIFO is full then); ``bus.cancel_scheduled()``
    takes back those not yet due. The sender hears them as its own (``is_rx`` False); a client does not
    count them in flight.
* **Bus states and error frames** (test hooks on the medium, ``bus.medium``): ``set_state(node,
  state)`` with python-can's ``BusState``: ACTIVE, PASSIVE (error passive) or ERROR (bus off;
  ``bus_states.BUS_OFF``). The node's ``bus.state`` reports it and its reader gets the SocketCAN
  controller error frame (CAN_ERR_CRTL with error-passive/active bits, CAN_ERR_BUSOFF,
  CAN_ERR_RESTARTED on recovery). Bus off: ``send()`` raises CanOperationError (ENETDOWN), its
  queued frames are dropped (one on the wire aborted), it receives nothing. ``inject_error_frame()``
  delivers an error frame (``is_error_frame``, default CAN_ERR_PROT) to every node not bus off; it
  takes no bus time in the accounting.
* **Accounting** (``Medium.stats()`` -> ``WireStats``; ``Medium.accounting``: ``records()``,
  ``load(t0, t1)``, ``period_loads()``, ``late_syncs()``, ``sync_intervals()``): per frame start, end, identifier,
  DLC and sender; bus load per SYNC period; late SYNCs (lockstep: started more than 5 % of the
  period after their nominal time; wall: more than that after the previous SYNC's start + period);
  max FIFO depth and ENOBUFS count per node; error frames injected.
* **Other processes** (``server.serve_wire``): a process serves its medium of a channel on
  127.0.0.1:PORT; another opens ``channel="NAME@127.0.0.1:PORT"``. Only loopback is served or
  connected to. In lockstep every send is acknowledged synchronously by the server (ENOBUFS at
  ``send()``, exactly as in-process); on the wall clock sends are pipelined and the client counts
  its frames in flight (frames still in the socket count as queued; a sender waiting for room reads
  the server's reports itself; ``bus.coalesced()`` sends a thread's run of frames in one write, each
  still counted and refused on its own, and a frame posted never waits for another thread's request
  to be answered). Frames stream back on a second connection; a remote bus's ``state`` is what the
  controller error frames it received say (no round trip). One selector thread
  serves every socket of the server. The wire's threads ask for SCHED_FIFO (``priority``: they
  stand in for the controller and the kernel). ``bus.medium`` is then a
  ``client.RemoteMedium`` with the same ``stats``, ``set_state`` and ``inject_error_frame``.
"""

from pvtflow.axes.sim.wire.accounting import LateSync, WireFrame, WireStats
from pvtflow.axes.sim.wire.bus_states import BUS_OFF, ERROR_PASSIVE
from pvtflow.axes.sim.wire.interface import SimWireBus, parse_channel
from pvtflow.axes.sim.wire.medium import Medium, WireConfigError
from pvtflow.axes.sim.wire.server import WireServer, serve_wire

__all__ = [
    "BUS_OFF",
    "ERROR_PASSIVE",
    "LateSync",
    "Medium",
    "SimWireBus",
    "WireConfigError",
    "WireFrame",
    "WireServer",
    "WireStats",
    "parse_channel",
    "serve_wire",
]
