"""A simulated multicopter on a MAVLink 2 link (common dialect): the I/O loop.

One :class:`MavlinkVehicle` = one system id, component 1, on one transport (``udpout:``,
``udpin:`` or ``tcpin:``, see :mod:`sim_vehicle.transport`). This module is the thin shell:
``select`` over the transport, one pymavlink parser per peer (pymavlink is only the codec),
flood and target filtering with counters, and the wall clock that paces the simulation.
Everything else is I/O-free and lives beside it:

:mod:`sim_vehicle.autopilot`
    modes, arming, commands, parameters, mission protocol; one class per personality
    (:class:`~sim_vehicle.px4.Px4Autopilot`, :class:`~sim_vehicle.ardupilot.ArduCopterAutopilot`).
:mod:`sim_vehicle.navigator`
    mission items -> flight activities (the onboard tracer for contour items).
:mod:`sim_vehicle.telemetry`
    message builders, stream rates, samples, the outbox this loop drains.
:mod:`sim_vehicle.state`
    the vehicle state they share.

Time: sim time runs ``SPEEDUP`` times faster than wall time; one sim tick = one sensor
period. Ticks due are run in batches (at most every :data:`TICK_BATCH_WALL_S` of wall time) so
their samples share one vectorised geodetic conversion; the loop keeps serving I/O at least
every 20 ms of wall time and stops catching up when it falls more than half a wall second
behind (:attr:`MavlinkVehicle.behind_events`).

Robustness: garbage, bad-CRC and truncated packets, messages for other systems/components,
and more than :data:`RX_BUDGET_PER_S` messages per second from one peer are dropped and
counted in :attr:`MavlinkVehicle.counters`; REQUEST_MESSAGE(STATUSTEXT=253) answers with a
one-line summary, and ``sim-vehicle`` prints it at exit.
"""

from __future__ import annotations

import contextlib
import logging
import select
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.geometry import Region
from econdor_gcs.link.signing import (
    SigningKey,
    SigningStore,
    refusal_counts,
    refused,
    share_signing,
)

from .ardupilot import ArduCopterAutopilot
from .autopilot import Autopilot
from .body import SimBody
from .mission_server import MissionServer
from .px4 import Px4Autopilot
from .state import VehicleSettings, VehicleState
from .tracer import TracerParams
from .transport import Endpoint, Transport, open_transport, parse_endpoint

__all__ = ["AUTOPILOTS", "COMPONENT_ID", "MavlinkVehicle", "VehicleSettings"]

log = logging.getLogger("sim_vehicle")

COMPONENT_ID = mavlink.MAV_COMP_ID_AUTOPILOT1
RX_BUDGET_PER_S = 5000
"""Messages per wall second accepted from one peer; the rest is dropped as a flood."""
TICK_BATCH_WALL_S = 0.01
SERVE_IO_WALL_S = 0.02
"""Run ticks for at most this long before serving I/O again."""
MAX_PARSERS = 32

AUTOPILOTS: dict[str, type[Autopilot]] = {"px4": Px4Autopilot, "ardupilot": ArduCopterAutopilot}
"""The personalities, by the name ``sim-vehicle --autopilot`` takes."""


def _reset_parser(parser: mavlink.MAVLink) -> None:
    parser.buf = bytearray()
    parser.buf_index = 0
    parser.expected_length = mavlink.HEADER_LEN_V1 + 2


class _Sink:
    """File-like shim: pymavlink's MAVLink.send() writes here, we forward to the transport."""

    def __init__(self) -> None:
        self.chunks: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.chunks.append(bytes(data))


class MavlinkVehicle:
    """One simulated vehicle on one MAVLink transport.

    Parameters
    ----------
    field, region, origin
        The true field ``field(x, y)``, the mission area (local ENU metres) and its origin.
    settings
        :class:`VehicleSettings` (sysid, speeds, rates, speedup, ...).
    connect
        Endpoint string or :class:`~sim_vehicle.transport.Endpoint`; port 0 with ``udpin``
        or ``tcpin`` binds an ephemeral port (read :attr:`local_address`).
    home
        ``(lat, lon, alt_amsl)``; default the mission origin. The vehicle starts landed
        and disarmed at home.
    tracer_params
        Base :class:`TracerParams` (speeds are overridden by SPEED_MPS).
    autopilot
        The personality: an :class:`~sim_vehicle.autopilot.Autopilot` subclass (see
        :data:`AUTOPILOTS`); ``settings.companion`` says whether it accepts contour items.
    signing
        MAVLink 2 signing: everything sent is signed; unsigned and wrongly signed messages
        (commands, mission uploads, anything) are ignored and counted (``rx_unsigned``,
        ``rx_bad_signature``).
    """

    def __init__(
        self,
        field: Callable[[float, float], float],
        region: Region,
        origin: Origin,
        settings: VehicleSettings | None = None,
        connect: str | Endpoint = "udpout:127.0.0.1:14550",
        home: tuple[float, float, float] | None = None,
        tracer_params: TracerParams | None = None,
        autopilot: type[Autopilot] = Px4Autopilot,
        signing: SigningKey | None = None,
    ) -> None:
        s = settings or VehicleSettings()
        self.sysid = s.sysid
        home = home or (origin.lat_deg, origin.lon_deg, origin.alt_m)
        self.endpoint = parse_endpoint(connect) if isinstance(connect, str) else connect
        self.transport: Transport = open_transport(self.endpoint)
        self.autopilot = autopilot(field, region, origin, s, home, tracer_params,
                                   status_line=self.counters_line, now=time.monotonic())
        self.mav = mavlink.MAVLink(_Sink(), srcSystem=self.sysid, srcComponent=COMPONENT_ID)
        self.mav.robust_parsing = True
        self.signing = signing
        self._signing_state: Any = None
        """One pymavlink signing state for every peer's parser: the streams' timestamps are
        shared, so a packet replayed from another address is refused too."""
        self.signing_store: SigningStore | None = None
        """The vehicle's signing timestamps on disk: a command captured before a restart and
        replayed after it is refused (the MAVLink guide asks them kept)."""
        if signing is not None:
            signing.apply(self.mav)
            checker = mavlink.MAVLink(None)
            signing.apply(checker, sign_outgoing=False)
            self._signing_state = checker.signing
            self.signing_store = SigningStore(signing, s.sysid)
            self.signing_store.load(self.mav.signing, self._signing_state)
            if self.signing_store.error:
                log.warning("sysid %d: %s", s.sysid, self.signing_store.error)
        self.io_counters: dict[str, int] = {
            "rx_packets": 0, "rx_bad": 0, "rx_other_target": 0, "rx_flood": 0, "tx_packets": 0,
            "rx_unsigned": 0, "rx_bad_signature": 0,
        }
        self._parsers: dict[object, mavlink.MAVLink] = {}
        self._rx_window: dict[object, list[float]] = {}
        self._stop = threading.Event()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._thread: threading.Thread | None = None
        self._wall0 = 0.0
        self._sim_ref = 0.0
        self._wall_ref = 0.0
        self._speedup_ref = self.state.params["SPEEDUP"]
        self.started_wall = 0.0
        self.behind_events = 0
        self.tx_filter: Callable[[Any], bool] | None = None
        """Test hook: called with each outgoing message; return False to drop it."""

    # ------------------------------------------------------------------ construction

    @classmethod
    def from_mission(cls, mission: Any, sysid: int = 1, connect: str | Endpoint = "",
                     speedup: float | None = None, seed: int | None = None,
                     home: tuple[float, float, float] | None = None,
                     autopilot: type[Autopilot] = Px4Autopilot,
                     signing: SigningKey | None = None,
                     **overrides: Any) -> MavlinkVehicle:
        """Build a vehicle from a loaded :class:`econdor_gcs.config.Mission`."""
        v = mission.vehicles
        settings = VehicleSettings(
            sysid=sysid, speed_mps=v.speed_mps, max_speed_mps=v.max_speed_mps,
            max_accel_mps2=v.max_accel_mps2, max_turn_rate_dps=v.max_turn_rate_dps,
            sample_rate_hz=v.sample_rate_hz, altitude_m=v.altitude_m, noise_std=v.noise_std,
            lag_s=v.sensor.lag_s, position_std_m=v.sensor.position_std_m,
            position_tau_s=v.sensor.position_tau_s,
            speedup=v.speedup if speedup is None else speedup,
            search_radius_m=mission.algorithm.search_radius_m,
            tel_rate_hz=min(10.0, v.sample_rate_hz),
            seed=mission.seed if seed is None else seed,
        )
        for k, val in overrides.items():
            setattr(settings, k, val)
        field = mission.build_field(settings.seed)
        # the onboard tracer is told the sensor's lag when the station is (it corrects for
        # it), as in the in-process mode
        known_lag_s = v.sensor.lag_s if v.sensor.lag_correction == "deconvolve" else 0.0
        return cls(field, mission.region, mission.origin, settings,
                   connect or "udpout:127.0.0.1:14550",
                   tracer_params=TracerParams(sensor_lag_s=known_lag_s), home=home,
                   autopilot=autopilot, signing=signing)

    # ------------------------------------------------------------------ views

    @property
    def state(self) -> VehicleState:
        return self.autopilot.state

    @property
    def server(self) -> MissionServer:
        return self.autopilot.server

    @property
    def settings(self) -> VehicleSettings:
        return self.state.settings

    @property
    def params(self) -> dict[str, float]:
        return self.state.params

    @property
    def body(self) -> SimBody:
        return self.state.body

    @property
    def armed(self) -> bool:
        return self.state.armed

    @property
    def speed_mps(self) -> float:
        return self.state.speed_mps

    @property
    def counters(self) -> dict[str, int]:
        """Link and simulation counters (a snapshot)."""
        c = self.io_counters
        ap = self.autopilot.counters
        return {"rx_packets": c["rx_packets"], "rx_bad": c["rx_bad"],
                "rx_other_target": c["rx_other_target"], "rx_flood": c["rx_flood"],
                "rx_unhandled": ap["rx_unhandled"], "tx_packets": c["tx_packets"],
                "rx_unsigned": c["rx_unsigned"], "rx_bad_signature": c["rx_bad_signature"],
                "samples": len(self.autopilot.outbox.archive),
                "samples_resent": self.autopilot.outbox.samples_resent, "ticks": ap["ticks"],
                "commands": ap["commands"]}

    @property
    def local_address(self) -> tuple[str, int]:
        return self.transport.local_address

    @property
    def sim_time_s(self) -> float:
        return self.body.t_s

    @property
    def odometer_m(self) -> float:
        return self.state.odometer_m

    def counters_line(self) -> str:
        c = self.io_counters
        return (f"rx {c['rx_packets']} bad {c['rx_bad']} other {c['rx_other_target']} "
                f"flood {c['rx_flood']} unsigned {c['rx_unsigned']} badsig "
                f"{c['rx_bad_signature']} tx {c['tx_packets']} drop {self.transport.tx_dropped}")

    def achieved_speedup(self) -> float:
        wall = time.monotonic() - self._wall0
        return self.body.t_s / wall if wall > 0 else 0.0

    # ------------------------------------------------------------------ running

    def start(self) -> MavlinkVehicle:
        """Run the loop on a daemon thread (in-process use)."""
        self._thread = threading.Thread(target=self.run, name=f"sim-vehicle-{self.sysid}",
                                        daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        """Stop the loop (from any thread) and wait for it; closes the sockets."""
        self.request_stop()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)
            self._thread = None

    def request_stop(self) -> None:
        """Signal-handler-safe stop request."""
        self._stop.set()
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")

    def run(self) -> None:
        """The main loop; returns after :meth:`stop` / :meth:`request_stop`."""
        ap = self.autopilot
        now = time.monotonic()
        self._wall0 = self._wall_ref = self.started_wall = now
        self._sim_ref = self.body.t_s
        next_hb = now
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if now >= next_hb:
                    ap.one_hz(now)
                    if self.signing_store is not None:
                        self.signing_store.save_due(self.mav.signing, self._signing_state)
                    next_hb += 1.0
                    if next_hb < now:
                        next_hb = now + 1.0
                self._advance(now)
                ap.telemetry.periodic(time.monotonic())
                dl = ap.next_deadline()
                if dl is not None and time.monotonic() >= dl:
                    # a transfer deadline passed while we were busy: the awaited item may
                    # be sitting in the socket, so read before declaring a timeout
                    self._receive()
                ap.poll(time.monotonic())
                self._send_queued()
                self.transport.flush()
                timeout = self._next_timeout(next_hb)
                rlist = [*self.transport.fileno_list(), self._wake_r]
                wlist = self.transport.want_write()
                try:
                    readable, _, _ = select.select(rlist, wlist, [], timeout)
                except (InterruptedError, ValueError):
                    continue
                if self._wake_r in readable:
                    with contextlib.suppress(OSError):
                        self._wake_r.recv(64)
                if readable:
                    self._receive()
        finally:
            self.close()

    def close(self) -> None:
        if self.signing_store is not None:
            self.signing_store.save(self.mav.signing, self._signing_state)
        with contextlib.suppress(OSError):
            self.transport.close()
        for s in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                s.close()

    def _next_timeout(self, next_hb: float) -> float:
        now = time.monotonic()
        t = next_hb
        body = self.body
        t_tick = self._wall_ref + (body.t_s + body.dt_s - self._sim_ref) / self._speedup()
        # wake for ticks at most every TICK_BATCH_WALL_S: the ticks due by then run in one
        # go, so their samples share one vectorised geodetic conversion (I/O still wakes us)
        t = min(t, max(t_tick, now + TICK_BATCH_WALL_S))
        dl = self.autopilot.next_deadline()
        if dl is not None:
            t = min(t, dl)
        return max(0.0, min(t - now, 0.1))

    def _speedup(self) -> float:
        """SPEEDUP; when a GCS changed it, the clock is re-anchored at the current time."""
        speedup = self.state.params["SPEEDUP"]
        if speedup != self._speedup_ref:
            self._speedup_ref = speedup
            self._sim_ref = self.body.t_s
            self._wall_ref = time.monotonic()
        return speedup

    def _advance(self, wall: float) -> None:
        """Run the sim ticks due at wall time ``wall``."""
        ap = self.autopilot
        speedup = self._speedup()
        target = self._sim_ref + (wall - self._wall_ref) * speedup
        dt = self.body.dt_s
        if ap.parked:
            # nothing to sense or report: skip the idle ticks in one jump
            n = int((target - self.body.t_s) / dt + 1e-9)
            if n > 0:
                ap.skip_parked(n)
            return
        budget_end = wall + SERVE_IO_WALL_S
        while self.body.t_s + dt <= target + 1e-9:
            ap.tick()
            if time.monotonic() > budget_end:
                break
        self._send_queued()
        # fallen behind by more than half a second of wall time: stop trying to catch up
        if target - self.body.t_s > 0.5 * speedup:
            self.behind_events += 1
            self._sim_ref = self.body.t_s
            self._wall_ref = time.monotonic()

    # ------------------------------------------------------------------ receiving

    def _receive(self) -> None:
        now = time.monotonic()
        for peer, data in self.transport.recv_all(256):
            parser = self._parsers.get(peer)
            if parser is None:
                if len(self._parsers) > MAX_PARSERS:
                    self._parsers.clear()
                parser = mavlink.MAVLink(None)
                parser.robust_parsing = True
                if self._signing_state is not None:
                    share_signing(parser, self._signing_state)
                self._parsers[peer] = parser
            if not self.transport.stream and parser.buf_len() > 0:
                # a datagram is self-contained: leftovers of the previous one are garbage
                self.io_counters["rx_bad"] += 1
                _reset_parser(parser)
            before = refusal_counts(parser.signing)
            try:
                msgs = parser.parse_buffer(data) or []
            except Exception:  # noqa: BLE001 - never let a peer's bytes kill the vehicle
                self.io_counters["rx_bad"] += 1
                _reset_parser(parser)
                continue
            # a signed vehicle ignores unsigned and wrongly signed messages (counted apart)
            wrong, unsigned = refused(parser.signing, before)
            self.io_counters["rx_bad_signature"] += wrong
            self.io_counters["rx_unsigned"] += unsigned
            refusals = wrong + unsigned
            for msg in msgs:
                if isinstance(msg, mavlink.MAVLink_bad_data):
                    if refusals > 0:
                        refusals -= 1
                    else:
                        self.io_counters["rx_bad"] += 1
                    continue
                if not self._budget_ok(peer, now):
                    self.io_counters["rx_flood"] += 1
                    continue
                self.io_counters["rx_packets"] += 1
                try:
                    self._dispatch(msg, now)
                except Exception:  # noqa: BLE001
                    log.exception("sysid %d: error handling %s", self.sysid, msg.get_type())
                    self.io_counters["rx_bad"] += 1
        self._send_queued()

    def _budget_ok(self, peer: object, now: float) -> bool:
        w = self._rx_window.get(peer)
        if w is None or now - w[0] >= 1.0:
            self._rx_window[peer] = [now, 1]
            if len(self._rx_window) > 64:
                self._rx_window = {peer: [now, 1]}
            return True
        w[1] += 1
        return w[1] <= RX_BUDGET_PER_S

    def _dispatch(self, msg: Any, now: float) -> None:
        ts = getattr(msg, "target_system", None)
        if ts is not None and ts not in (0, self.sysid):
            self.io_counters["rx_other_target"] += 1
            return
        tc = getattr(msg, "target_component", None)
        if tc is not None and tc not in (0, COMPONENT_ID) and msg.get_type() != "MISSION_ACK":
            self.io_counters["rx_other_target"] += 1
            return
        self.autopilot.receive(msg, now)

    # ------------------------------------------------------------------ sending

    def _send_queued(self) -> None:
        """Send everything the autopilot queued, in order."""
        outbox = self.autopilot.outbox
        if not len(outbox):
            return
        for msg in outbox.drain(time.monotonic()):
            self._send_now(msg)

    def _send_now(self, msg: Any) -> None:
        if self.tx_filter is not None and not self.tx_filter(msg):
            return
        sink: _Sink = self.mav.file
        self.mav.send(msg)
        for chunk in sink.chunks:
            self.transport.send(chunk)
        sink.chunks.clear()
        self.io_counters["tx_packets"] += 1
