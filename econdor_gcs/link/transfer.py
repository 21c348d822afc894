"""MAVLink mission and command protocols as pure state machines (no I/O, time passed in).

Every machine has the same small interface, in the style of aioquic's connection objects:

``poll(now) -> list[message]``
    messages to send now: the first request, answers to what was received, and retries when a
    deadline passed.  Call it after every :meth:`receive` and whenever :meth:`next_deadline`
    is reached.
``receive(msg, now) -> None``
    feed one message that came from the target vehicle (the shell routes by system id).
``next_deadline() -> float | None``
    when :meth:`poll` must be called again even if nothing arrives (``None`` once done).
``done``, ``result``, ``error``
    ``error`` is an exception instance (:class:`~econdor_gcs.errors.ProtocolError` for a refusal,
    :class:`~econdor_gcs.errors.VehicleTimeout` when the retries ran out) or ``None``.

``now`` is any monotonic clock in seconds.  Machines ignore messages that do not belong to
them (other message types, other mission types, stale answers), so several can listen to one
vehicle's stream.

The items and plans themselves are in :mod:`.items`. Mission
conventions (DESIGN.md §4): items are ``MISSION_ITEM_INT`` in
``MAV_FRAME_GLOBAL_RELATIVE_ALT_INT``, mission type 0, "item 0 home, takeoff, trace items, then
return or loiter", exactly one item with ``current = 1`` (item 0).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

from econdor_gcs.errors import CommandRejected, MissionRejected, ProtocolError, VehicleTimeout
from econdor_gcs.link.codec import MAVLinkMessage, mavlink
from econdor_gcs.link.items import MissionItemSpec, command_name, enum_name

__all__ = [
    "DEFAULT_RETRIES",
    "DEFAULT_TIMEOUT_S",
    "CommandSender",
    "MissionClear",
    "MissionDownloader",
    "MissionUploader",
]

DEFAULT_TIMEOUT_S = 1.5
DEFAULT_RETRIES = 5


# --------------------------------------------------------------------------------------------
# state machines


class _Machine:
    """Shared bookkeeping: outbox, one deadline, a retry budget, the outcome."""

    what = "protocol"

    def __init__(self, target_system: int, target_component: int, timeout_s: float,
                 retries: int) -> None:
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be positive, got {timeout_s}")
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        self.target_system = target_system
        self.target_component = target_component
        self.timeout_s = timeout_s
        self.retries = retries
        self.done = False
        self.result: object = None
        self.error: Exception | None = None
        self.retries_used = 0  # in total, for statistics
        self._retries_left = retries
        self._deadline: float | None = None
        self._started = False
        self._outbox: list[MAVLinkMessage] = []
        self._last: MAVLinkMessage | None = None

    # -- interface --------------------------------------------------------------------------
    def poll(self, now: float) -> list[MAVLinkMessage]:
        if not self._started and not self.done:
            self._started = True
            self._start(now)
        elif not self.done and self._deadline is not None and now >= self._deadline:
            if self._retries_left > 0:
                self._retries_left -= 1
                self.retries_used += 1
                self._retry(now)
            else:
                self._fail(VehicleTimeout(
                    f"vehicle {self.target_system} did not answer {self.what} "
                    f"({self._waiting_for()}) after {self.retries} retries of "
                    f"{self.timeout_s:g} s"))
        out, self._outbox = self._outbox, []
        return out

    def receive(self, msg: MAVLinkMessage, now: float) -> None:
        if self.done or not self._started:
            return
        self._on_message(msg, now)

    def next_deadline(self) -> float | None:
        if self.done:
            return None
        if not self._started:
            return float("-inf")  # poll at once
        return self._deadline

    # -- helpers for subclasses ---------------------------------------------------------------
    def _send(self, msg: MAVLinkMessage, now: float, *, progress: bool = False) -> None:
        """Queue ``msg``, remember it for a resend, arm the deadline."""
        self._outbox.append(msg)
        self._last = msg
        self._deadline = now + self.timeout_s
        if progress:
            self._retries_left = self.retries

    def _retry(self, now: float) -> None:
        if self._last is not None:
            self._send(self._last, now)

    def _succeed(self, result: object) -> None:
        self.done = True
        self.result = result
        self._deadline = None

    def _fail(self, error: Exception) -> None:
        self.done = True
        self.error = error
        self._deadline = None

    def _mine(self, msg: MAVLinkMessage, mission_type: int) -> bool:
        return (getattr(msg, "mission_type", 0) or 0) == mission_type

    def _start(self, now: float) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _on_message(self, msg: MAVLinkMessage, now: float) -> None:  # pragma: no cover
        raise NotImplementedError

    def _waiting_for(self) -> str:
        return "no answer"


MAYBE_STALE_RESULTS = frozenset({mavlink.MAV_MISSION_INVALID_SEQUENCE, mavlink.MAV_MISSION_ERROR,
                                 mavlink.MAV_MISSION_OPERATION_CANCELLED})
"""MISSION_ACK results that may answer a copy of an item, or an item of an earlier transfer,
rather than the transfer running: a verdict only when no request follows."""


class MissionUploader(_Machine):
    """Upload ``items`` (GCS side of MISSION_COUNT -> MISSION_REQUEST(_INT) -> ... -> MISSION_ACK).

    The vehicle pulls items in any order (re-requests are answered again).  ``MISSION_REQUEST``
    (the float protocol, ArduPilot's habit) is answered with ``MISSION_ITEM_INT`` as the MAVLink
    spec allows, or with a float ``MISSION_ITEM`` if ``legacy_items`` is set.  On a timeout the
    last message (``MISSION_COUNT`` or the last item) is sent again; ``retries`` resends per
    step.  ``result`` is the number of items on success.

    The items' ``seq`` must be ``0..n-1`` in order; their ``mission_type`` is forced to
    ``mission_type``.

    ``MAV_MISSION_INVALID_SEQUENCE`` during the transfer is an answer to a stale copy of an
    item, not the end of it: ArduPilot requests an item again after one second of *its* time
    (0.1 s of wall time at a 10x speed-up), so a busy station answers both requests, and the
    second copy arrives when ArduPilot already waits for the next item; it says
    INVALID_SEQUENCE and goes on requesting. The same holds for ERROR and OPERATION_CANCELLED
    (:data:`MAYBE_STALE_RESULTS`): ArduPilot answers them to an item of a transfer it has
    ended, so after the station starts an upload again, the answer to the last item of the
    attempt before can arrive when the new transfer is running. Only when no request follows
    within the timeout is such an answer the vehicle's verdict (a vehicle with no transfer
    running), and the upload fails with it (``stale_acks`` counts the others).

    A request before item 0 was asked for that is not for item 0 of this transfer (another
    item, or another mission type) belongs to a transfer the vehicle began earlier with
    this station (one that died part-way, or whose cancel was lost): PX4 goes on asking for
    its items while it hears counts, refuses the new count with ERROR once it has an item,
    and answers one before that by asking for item 0 of the old transfer, in the old
    transfer's mission type. It is not answered (the new items must not complete the old
    transfer): the station cancels that transfer (MISSION_ACK(OPERATION_CANCELLED), in the
    request's mission type) and counts again, once per count sent
    (``stale_transfers`` counts them). An old transfer of the same type the vehicle asked
    item 0 of takes this transfer's items up to its own count: a request beyond this count,
    or an ACCEPTED before the last item was asked for, starts this one again the same way
    (a cancel, then the count), at most ``retries`` times.
    """

    what = "mission upload"

    def __init__(self, target_system: int, target_component: int,
                 items: Sequence[MissionItemSpec], mission_type: int = 0, *,
                 timeout_s: float = DEFAULT_TIMEOUT_S, retries: int = DEFAULT_RETRIES,
                 legacy_items: bool = False) -> None:
        super().__init__(target_system, target_component, timeout_s, retries)
        for i, item in enumerate(items):
            if item.seq != i:
                raise ValueError(
                    f"mission item {i} has seq {item.seq}; items must be numbered 0..n-1")
        self.items = [replace(it, mission_type=mission_type) for it in items]
        self.mission_type = mission_type
        self.legacy_items = legacy_items
        self.requested: set[int] = set()
        self.stale_acks = 0
        self.stale_transfers = 0
        self._stale_ended = False  # a stale transfer cancelled since the last count
        self._restarts_left = retries  # progress does not renew these
        self._last_seq: int | None = None
        self._invalid: MAVLinkMessage | None = None

    def _count_msg(self) -> MAVLinkMessage:
        return mavlink.MAVLink_mission_count_message(
            self.target_system, self.target_component, len(self.items), self.mission_type)

    def _start(self, now: float) -> None:
        self._send(self._count_msg(), now)

    def _end_stale(self, msg: MAVLinkMessage, now: float) -> None:
        """Cancel the earlier transfer ``msg`` asks for an item of, and count again."""
        if self._stale_ended:
            return  # its requests sent before the cancel arrived
        self._stale_ended = True
        self._count_again(now, getattr(msg, "mission_type", 0) or 0)

    def _count_again(self, now: float, cancel_type: int) -> None:
        """Cancel the vehicle's transfer of ``cancel_type``, then start this one again from
        the count."""
        self.stale_transfers += 1
        self.requested.clear()
        self._last_seq = None
        self._invalid = None  # an ERROR to the count was the old transfer's "busy"
        self._outbox.append(mavlink.MAVLink_mission_ack_message(
            self.target_system, self.target_component,
            mavlink.MAV_MISSION_OPERATION_CANCELLED, cancel_type))
        self._send(self._count_msg(), now)

    def _took_ours_into_another(self, now: float, what: str) -> None:
        """The vehicle ran our items into a transfer of another count (an earlier one of this
        station's it asked item 0 of): count again, at most ``retries`` times."""
        if self._restarts_left == 0:
            self._fail(ProtocolError(f"vehicle {self.target_system} {what}"))
            return
        self._restarts_left -= 1
        self._count_again(now, self.mission_type)

    def _waiting_for(self) -> str:
        if self._last_seq is None:
            return "no MISSION_REQUEST after MISSION_COUNT"
        if self._last_seq == len(self.items) - 1:
            return "no MISSION_ACK after the last item"
        return f"no request after item {self._last_seq}"

    def _on_message(self, msg: MAVLinkMessage, now: float) -> None:
        kind = msg.get_type()
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            seq = msg.seq
            if not self.requested and (seq != 0 or not self._mine(msg, self.mission_type)):
                self._end_stale(msg, now)  # a transfer begins at item 0 of its own type
                return
            if not self._mine(msg, self.mission_type):
                return
            if not 0 <= seq < len(self.items):
                self._took_ours_into_another(
                    now, f"requested mission item {seq} of a {len(self.items)}-item mission")
                return
            item = self.items[seq]
            if kind == "MISSION_REQUEST" and self.legacy_items:
                reply = item.to_legacy_message(self.target_system, self.target_component)
            else:
                reply = item.to_message(self.target_system, self.target_component)
            new = seq not in self.requested
            self.requested.add(seq)
            self._last_seq = seq
            self._invalid = None
            self._send(reply, now, progress=new)
        elif kind == "MISSION_ACK":
            if not self._mine(msg, self.mission_type):
                return
            if msg.type == mavlink.MAV_MISSION_ACCEPTED:
                # An ACCEPTED before the last item was asked for is a stale answer (e.g. to an
                # earlier clear), or, once items were asked for, the end of a shorter
                # transfer that took them; an empty mission is accepted right after the count.
                if not self.items or (len(self.items) - 1) in self.requested:
                    self._succeed(len(self.items))
                elif self.requested:
                    self._took_ours_into_another(
                        now, f"accepted {len(self.requested)} of {len(self.items)} items")
                return
            if msg.type in MAYBE_STALE_RESULTS:
                self.stale_acks += 1
                self._invalid = msg  # the verdict only if no request follows (_retry)
                return
            self._refused(msg)

    def _retry(self, now: float) -> None:
        if self._invalid is not None:
            self._refused(self._invalid)
        else:
            if not self.requested:
                self._stale_ended = False  # the count again: a stale request may follow
            super()._retry(now)

    def _refused(self, msg: MAVLinkMessage) -> None:
        result = enum_name("MAV_MISSION_RESULT", msg.type)
        seq = self._last_seq
        if seq is None:
            text = (f"vehicle {self.target_system} rejected the mission "
                    f"({len(self.items)} items): {result}")
        else:
            text = (f"vehicle {self.target_system} rejected mission item {seq}: "
                    f"{result}")
        command = self.items[seq].command if seq is not None else None
        self._fail(MissionRejected(text, int(msg.type), seq, command))


class MissionDownloader(_Machine):
    """Download the vehicle's mission: MISSION_REQUEST_LIST -> MISSION_COUNT ->
    MISSION_REQUEST_INT per item -> MISSION_ITEM_INT -> our MISSION_ACK.

    ``result`` is the list of :class:`MissionItemSpec` (legacy ``MISSION_ITEM`` answers are
    converted to ``_INT`` frames).  On a timeout the last request is repeated.
    """

    what = "mission download"

    def __init__(self, target_system: int, target_component: int, mission_type: int = 0, *,
                 timeout_s: float = DEFAULT_TIMEOUT_S, retries: int = DEFAULT_RETRIES) -> None:
        super().__init__(target_system, target_component, timeout_s, retries)
        self.mission_type = mission_type
        self.count: int | None = None
        self.items: list[MissionItemSpec] = []

    def _start(self, now: float) -> None:
        self._send(mavlink.MAVLink_mission_request_list_message(
            self.target_system, self.target_component, self.mission_type), now)

    def _waiting_for(self) -> str:
        if self.count is None:
            return "no MISSION_COUNT after MISSION_REQUEST_LIST"
        return f"no mission item {len(self.items)} of {self.count}"

    def _request(self, seq: int, now: float) -> None:
        self._send(mavlink.MAVLink_mission_request_int_message(
            self.target_system, self.target_component, seq, self.mission_type), now,
            progress=True)

    def _ack(self, result: int) -> MAVLinkMessage:
        return mavlink.MAVLink_mission_ack_message(
            self.target_system, self.target_component, result, self.mission_type)

    def _on_message(self, msg: MAVLinkMessage, now: float) -> None:
        kind = msg.get_type()
        if not self._mine(msg, self.mission_type):
            return
        if kind == "MISSION_COUNT":
            if self.count is not None:
                return  # a duplicate answer to a repeated MISSION_REQUEST_LIST
            self.count = msg.count
            if self.count == 0:
                self._outbox.append(self._ack(mavlink.MAV_MISSION_ACCEPTED))
                self._succeed([])
            else:
                self._request(0, now)
        elif kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            if self.count is None or msg.seq != len(self.items):
                return  # unsolicited or a duplicate; the pending request stands
            self.items.append(MissionItemSpec.from_message(msg))
            if len(self.items) < self.count:
                self._request(len(self.items), now)
            else:
                self._outbox.append(self._ack(mavlink.MAV_MISSION_ACCEPTED))
                self._succeed(list(self.items))
        elif kind == "MISSION_ACK" and msg.type != mavlink.MAV_MISSION_ACCEPTED:
            self._fail(ProtocolError(
                f"vehicle {self.target_system} refused the mission download: "
                f"{enum_name('MAV_MISSION_RESULT', msg.type)}"))


class MissionClear(_Machine):
    """MISSION_CLEAR_ALL -> MISSION_ACK (``result`` is ``True``).

    MISSION_ACK(OPERATION_CANCELLED) is no answer to a clear: it is a vehicle ending an
    upload it gave up waiting for (ArduPilot, 8 s of its time after an upload the station
    left part-way), which can arrive while the clear is on its way; the clear's own answer
    follows it."""

    what = "mission clear"

    def __init__(self, target_system: int, target_component: int, mission_type: int = 0, *,
                 timeout_s: float = DEFAULT_TIMEOUT_S, retries: int = DEFAULT_RETRIES) -> None:
        super().__init__(target_system, target_component, timeout_s, retries)
        self.mission_type = mission_type

    def _start(self, now: float) -> None:
        self._send(mavlink.MAVLink_mission_clear_all_message(
            self.target_system, self.target_component, self.mission_type), now)

    def _waiting_for(self) -> str:
        return "no MISSION_ACK after MISSION_CLEAR_ALL"

    def _on_message(self, msg: MAVLinkMessage, now: float) -> None:
        if msg.get_type() != "MISSION_ACK" or not self._mine(msg, self.mission_type):
            return
        if msg.type == mavlink.MAV_MISSION_OPERATION_CANCELLED:
            return  # the end of an upload, not this clear's answer
        if msg.type == mavlink.MAV_MISSION_ACCEPTED:
            self._succeed(True)
        else:
            self._fail(ProtocolError(
                f"vehicle {self.target_system} refused to clear its mission: "
                f"{enum_name('MAV_MISSION_RESULT', msg.type)}"))


class CommandSender(_Machine):
    """COMMAND_LONG -> COMMAND_ACK.

    A retry resends the command with ``confirmation`` incremented.  ``MAV_RESULT_IN_PROGRESS``
    keeps waiting (the deadline is pushed out, nothing is resent; ``progress`` holds the last
    percentage).  ``MAV_RESULT_ACCEPTED`` succeeds with the ``COMMAND_ACK`` as ``result``; any
    other result fails with a :class:`ProtocolError` naming the command and the result.
    """

    what = "command"

    def __init__(self, target_system: int, target_component: int, command: int,
                 params: Sequence[float] = (), *, timeout_s: float = DEFAULT_TIMEOUT_S,
                 retries: int = DEFAULT_RETRIES,
                 position: tuple[int, int, float] | None = None) -> None:
        super().__init__(target_system, target_component, timeout_s, retries)
        limit = 4 if position is not None else 7
        if len(params) > limit:
            raise ValueError(f"the command takes at most {limit} params, got {len(params)}")
        self.command = command
        self.params = [float(p) for p in params] + [0.0] * (7 - len(params))
        self.position = position
        """``(x, y, z)`` sends COMMAND_INT (exact int32 x/y, MAV_FRAME_GLOBAL_INT) instead of
        COMMAND_LONG."""
        self.confirmation = 0
        self.progress: int | None = None
        self.what = f"command {command_name(command)}"

    def _message(self) -> MAVLinkMessage:
        if self.position is not None:
            x, y, z = self.position
            return mavlink.MAVLink_command_int_message(
                self.target_system, self.target_component, mavlink.MAV_FRAME_GLOBAL_INT,
                self.command, 0, 0, *self.params[:4], x, y, z)
        return mavlink.MAVLink_command_long_message(
            self.target_system, self.target_component, self.command, self.confirmation % 256,
            *self.params)

    def _start(self, now: float) -> None:
        self._send(self._message(), now)

    def _retry(self, now: float) -> None:
        if self.progress is not None:  # in progress: keep waiting, do not restart the command
            self._deadline = now + self.timeout_s
            return
        self.confirmation += 1
        self._send(self._message(), now)

    def _waiting_for(self) -> str:
        return "no COMMAND_ACK" if self.progress is None else f"stalled at {self.progress} %"

    def _on_message(self, msg: MAVLinkMessage, now: float) -> None:
        if msg.get_type() != "COMMAND_ACK" or msg.command != self.command:
            return
        if msg.result == mavlink.MAV_RESULT_ACCEPTED:
            self._succeed(msg)
        elif msg.result == mavlink.MAV_RESULT_IN_PROGRESS:
            self.progress = msg.progress
            self._deadline = now + self.timeout_s
            self._retries_left = self.retries
        else:
            self._fail(CommandRejected(
                f"vehicle {self.target_system} answered {command_name(self.command)} with "
                f"{enum_name('MAV_RESULT', msg.result)}", self.command, int(msg.result)))
