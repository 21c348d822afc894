"""Unit tests of the ground station's pure parts (no sockets, no processes)."""

from __future__ import annotations

import asyncio
import json
import math
import time
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from econdor_gcs.config import parse_mission
from econdor_gcs.core.geodesy import Origin
from econdor_gcs.core.tasks import (
    SENSOR_LAG_COMMAND,
    OutcomeStatus,
    Phase,
    SampleLog,
    TaskOutcome,
    TaskStyle,
    TraceReport,
    TraceTask,
    Waypoint,
)
from econdor_gcs.errors import MissionRejected, ProtocolError, VehicleTimeout
from econdor_gcs.link.codec import mavlink
from econdor_gcs.link.items import build_mission, plan_mission
from econdor_gcs.link.reports import PhaseTrack, phase_change, trace_report
from econdor_gcs.link.router import Received, Sample, VehicleLink, VehicleLost
from econdor_gcs.station.executor import MavlinkExecutor
from econdor_gcs.station.flight import Flight, StatusAssembler, build_report
from econdor_gcs.station.sorties import UPLOAD_ATTEMPTS, mission_items_json

ORIGIN = Origin(47.397742, 8.545594, 488.0)


# -- machine-readable reports (PHASE, TRACE) and STATUSTEXT for people -------------------------


def _trace_msg(seq: int, report: TraceReport | None = None, data: list[float] | None = None,
               sysid: int = 2) -> Any:
    values = report.to_array() if report is not None else list(data or [])
    values += [0.0] * (58 - len(values))
    return rx(mavlink.MAVLink_debug_float_array_message(123, b"TRACE", seq, values), sysid)


def rx(msg: Any, sysid: int = 2) -> Any:
    """``msg`` as the station receives it from vehicle ``sysid`` (packed, then decoded)."""
    enc = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)
    return mavlink.MAVLink(None).decode(bytearray(msg.pack(enc)))


def test_trace_report_round_trips_through_mavlink() -> None:
    r = TraceReport(5, 1003, OutcomeStatus.LENGTH_LIMIT, 300.25, 1234.5, 41.5)
    assert trace_report(_trace_msg(5, r)) == r
    other = rx(mavlink.MAVLink_debug_float_array_message(1, b"OTHER", 5, [0.0] * 58))
    assert trace_report(other) is None
    with pytest.raises(ProtocolError, match="vehicle 2: .*unknown outcome status code 17"):
        trace_report(_trace_msg(5, data=[1003, 17, 1.0, 2.0, 0.0]))
    with pytest.raises(ProtocolError, match="must be integers"):
        trace_report(_trace_msg(5, data=[10.5, 1, 1.0, 2.0, 0.0]))
    with pytest.raises(ProtocolError, match="finite and >= 0"):
        trace_report(_trace_msg(5, data=[10, 1, -1.0, 2.0, 0.0]))


def test_outcome_status_codes_are_stable_and_unreported_has_none() -> None:
    codes = {s: s.code for s in OutcomeStatus if s is not OutcomeStatus.UNREPORTED}
    assert codes == {"reached": 0, "closed": 1, "boundary": 2, "length_limit": 3,
                     "not_found": 4, "lost": 5, "unreachable": 6}
    # every status the compiled tracer can end a task with is one the station knows
    from sim_vehicle.machine import STATUS_NAMES
    for name in STATUS_NAMES.values():
        if name != "budget":  # the tracer reports a spent trace budget as "lost"
            assert OutcomeStatus(name).code >= 0
    with pytest.raises(ValueError, match="no wire code"):
        _ = OutcomeStatus.UNREPORTED.code
    assert TaskOutcome(Waypoint(0, 0), "closed", 1.0).status is OutcomeStatus.CLOSED
    with pytest.raises(ValueError, match="'done' is not a valid OutcomeStatus"):
        TaskOutcome(Waypoint(0, 0), "done", 1.0)


def test_phase_changes_are_looked_up_by_sample_time() -> None:
    msg = rx(mavlink.MAVLink_named_value_int_message(2500, b"PHASE", int(Phase.TRACE)))
    assert phase_change(msg) == (2500, Phase.TRACE)
    assert phase_change(rx(mavlink.MAVLink_named_value_int_message(1, b"OTHER", 2))) is None
    with pytest.raises(ProtocolError, match="unknown phase 9"):
        phase_change(rx(mavlink.MAVLink_named_value_int_message(1, b"PHASE", 9)))
    track = PhaseTrack()
    track.add(1000, Phase.SEARCH)
    track.add(2500, Phase.TRACE)
    # a sample that arrives after the change but was taken before it keeps its phase
    assert [track.at(t) for t in (999, 1000, 2499, 2500)] == \
        [Phase.TRANSIT, Phase.SEARCH, Phase.SEARCH, Phase.TRACE]
    assert track.latest == Phase.TRACE


def test_status_assembler_joins_chunks() -> None:
    a = StatusAssembler()
    assert a.add(1, b"armed\x00\x00") == "armed"
    text = "piece 1003: length_limit traced 300.0 m flown 1234.5 m"  # > 50 bytes
    raw = text.encode()
    assert a.add(2, raw[:50], text_id=9, chunk_seq=0) is None
    assert a.add(1, b"short one") == "short one"  # other vehicles interleave freely
    assert a.add(2, raw[50:], text_id=9, chunk_seq=1) == text
    # exactly 50 bytes: completed by an empty terminator
    fifty = b"x" * 50
    assert a.add(3, fifty, text_id=4, chunk_seq=0) is None
    assert a.add(3, b"", text_id=4, chunk_seq=1) == "x" * 50


# -- geodesy --------------------------------------------------------------------------------


def _batch_executor() -> tuple[Any, Any]:
    m = parse_mission({"field": {"model": "paper"}})
    router = FakeRouter()
    ex = MavlinkExecutor(SimpleNamespace(router=router), m, [1])  # type: ignore[arg-type]
    return ex, router.handlers["sample"]


def test_sample_batches_match_origin_to_local() -> None:
    ex, on_sample = _batch_executor()
    origin = ex.origin
    rng = np.random.default_rng(0)
    pts = rng.uniform(-200, 1200, size=(50, 2))
    for k, (x, y) in enumerate(pts):
        lat, lon, _ = origin.to_global(float(x), float(y))
        on_sample(Sample(1, 1000 + 100 * k, lat, lon, 30.0, float(k)))
    v = ex.vehicles[1]
    assert len(v.raw) == 50 and not v.stray  # buffered raw until needed
    log = ex.pending_samples()  # converts the batch
    assert not v.raw
    for k, (x, y) in enumerate(pts):
        lat, lon, _ = origin.to_global(float(x), float(y))
        e2, n2, _ = origin.to_local(lat, lon)
        assert log.x_m[k] == pytest.approx(e2, abs=1e-6)
        assert log.y_m[k] == pytest.approx(n2, abs=1e-6)
        # the vehicle's point (up = 0) lies a few cm above the origin's ellipsoid height at
        # 1 km; the horizontal effect of that is micrometres
        assert log.x_m[k] == pytest.approx(x, abs=1e-4)
        assert log.y_m[k] == pytest.approx(y, abs=1e-4)
    np.testing.assert_allclose(log.value, np.arange(50.0))
    np.testing.assert_allclose(log.t_s, 1.0 + 0.1 * np.arange(50))
    flown = float(np.sum(np.hypot(*np.diff(pts, axis=0).T)))
    assert v.flown_m == pytest.approx(flown, abs=1e-3)
    assert v.last_xy == pytest.approx(tuple(pts[-1]), abs=1e-4)


def test_sample_batches_convert_when_full_and_continue_the_path() -> None:
    from econdor_gcs.station.telemetry import SAMPLE_BATCH

    ex, on_sample = _batch_executor()
    n = SAMPLE_BATCH + 10
    for k in range(n):
        lat, lon, _ = ex.origin.to_global(float(k), 0.0)
        on_sample(Sample(1, k, lat, lon, 30.0, 0.0))
    v = ex.vehicles[1]
    assert len(v.raw) == 10 and sum(len(b) for b in v.stray) == SAMPLE_BATCH
    # the path length runs across batch boundaries without a gap or a double count
    assert ex.status_rows()[0].flown_m == pytest.approx(n - 1, abs=1e-3)
    assert len(ex.pending_samples()) == n


def test_integer_coordinates_cost_about_a_centimetre() -> None:
    lat, lon, _ = ORIGIN.to_global(37.123456, 81.987654)
    e, n, _ = ORIGIN.to_local_many([round(lat * 1e7) / 1e7], [round(lon * 1e7) / 1e7])
    assert math.hypot(e[0] - 37.123456, n[0] - 81.987654) < 0.012


# -- reports --------------------------------------------------------------------------------


def test_build_report_from_a_flight() -> None:
    wp = Waypoint(10.0, 0.0)
    tr = TraceTask(level=50.0, x_m=10.0, y_m=10.0, search_radius_m=10.0, max_length_m=0.0,
                   piece_id=1001)
    f = Flight(index=2, sysid=3, tasks=[wp, tr], start_xy=(0.0, 0.0), start_ms=1000)
    f.samples = SampleLog.from_rows([(1.1, 3.0, 4.0, 1.0, Phase.TRANSIT),
                                     (1.2, 6.0, 8.0, 2.0, Phase.TRANSIT),
                                     (1.3, 6.0, 9.0, 3.0, Phase.TRACE)], vehicle=2)
    f.last_ms = 3500
    f.item_flown_m = {2: 10.0, 3: 1.0}
    f.pieces[1001] = TraceReport(3, 1001, OutcomeStatus.CLOSED, 42.0, 50.0)
    f.done = True
    r = build_report(f)
    assert r.vehicle == 2 and len(r.samples) == 3
    assert set(r.samples.vehicle) == {2}
    assert list(r.samples.phase) == [Phase.TRANSIT, Phase.TRANSIT, Phase.TRACE]
    assert r.flown_m == pytest.approx(5.0 + 5.0 + 1.0)
    assert r.traced_m == 42.0
    assert [o.status for o in r.outcomes] == ["reached", "closed"]
    assert r.outcomes[0].flown_m == 10.0 and r.outcomes[1].flown_m == 50.0
    assert (r.end_x_m, r.end_y_m) == (6.0, 9.0)
    assert r.sim_s == pytest.approx(2.5)


def test_build_report_of_an_unfinished_flight() -> None:
    tr = TraceTask(50.0, 1.0, 1.0, 10.0, 0.0, 5)
    f = Flight(index=0, sysid=1, tasks=[Waypoint(1.0, 1.0), tr], start_xy=(2.0, 3.0))
    r = build_report(f)
    assert len(r.samples) == 0 and r.flown_m == 0.0 and r.sim_s == 0.0
    assert [o.status for o in r.outcomes] == ["unreported", "unreported"]
    assert (r.end_x_m, r.end_y_m) == (2.0, 3.0)


def test_mission_json_round_trip() -> None:
    items = build_mission(ORIGIN, [Waypoint(5.0, 5.0), TraceTask(20.0, 10, 10, 8, 0, 9)], 30.0,
                          end="none")
    data = json.loads(mission_items_json(items))
    assert [d["command"] for d in data] == [16, 22, 16, 31000]
    assert data[3]["param1"] == 20.0 and data[3]["param4"] == 9.0


# -- the executor's message handling, with a stand-in router ----------------------------------


class FakeRouter:
    def __init__(self) -> None:
        # vehicles heard just now (a silent one's item time limits are not watched)
        self.vehicles = {s: VehicleLink(s, ("127.0.0.1", 1),
                                        last_heartbeat=time.monotonic()) for s in (1, 2)}
        self.handlers: dict[str, Any] = {}

    def received(self, sysid: int, msg: Any) -> Received:
        """``msg`` taken in by the vehicle's link first, as the router's table does."""
        if msg.get_type() != "HEARTBEAT":
            self.vehicles[sysid].account(msg, time.monotonic())
        return Received(sysid, msg)

    def subscribe(self, kinds: Any, h: Any) -> None:
        kinds = kinds if isinstance(kinds, tuple) else (kinds,)
        if Sample in kinds:
            self.handlers["sample"] = h
        elif Received in kinds:
            self.handlers["message"] = lambda sysid, msg: h(self.received(sysid, msg))
        else:
            self.handlers["event"] = h


def _mission() -> Any:
    return parse_mission({"field": {"model": "paper"}})


def _sample(frame_origin: Origin, sysid: int, ms: int, x: float, y: float, value: float
            ) -> Sample:
    lat, lon, _ = frame_origin.to_global(x, y)
    return Sample(sysid, ms, round(lat * 1e7) / 1e7, round(lon * 1e7) / 1e7, 30.0, value)


def test_executor_collects_samples_phases_and_outcomes() -> None:
    m = _mission()
    router = FakeRouter()
    ex = MavlinkExecutor(SimpleNamespace(router=router), m, [1, 2])  # type: ignore[arg-type]
    tr = TraceTask(50.0, 10.0, 10.0, 10.0, 0.0, 1000)
    items = build_mission(m.origin, [tr], 30.0, end="none")
    v = ex.vehicles[2]
    v.items = items
    f = ex.telemetry.begin(v, [tr])
    v.status = "flying"
    on_msg, on_sample = router.handlers["message"], router.handlers["sample"]
    on_msg(2, mavlink.MAVLink_mission_current_message(2, 3, 2, 1))
    on_msg(2, rx(mavlink.MAVLink_named_value_int_message(900, b"PHASE", int(Phase.SEARCH))))
    on_sample(_sample(m.origin, 2, 1000, 1.0, 0.0, 10.0))
    # the text is for people: it changes no phase and no outcome
    on_msg(2, mavlink.MAVLink_statustext_message(6, b"piece 1000: contour found", 0, 0))
    on_msg(2, rx(mavlink.MAVLink_named_value_int_message(1100, b"PHASE", int(Phase.TRACE))))
    on_sample(_sample(m.origin, 2, 1100, 2.0, 0.0, 11.0))
    on_sample(_sample(m.origin, 2, 1050, 1.5, 0.0, 10.5))  # late, taken before the change
    on_sample(_sample(m.origin, 1, 1100, 50.0, 50.0, 99.0))  # another vehicle, not flying
    on_msg(2, mavlink.MAVLink_statustext_message(
        6, b"piece 1000: closed traced 999.0 m flown 999.0 m", 0, 0))
    assert not f.pieces and ex.status_rows()[1].message.endswith("flown 999.0 m")
    on_msg(2, _trace_msg(2, TraceReport(2, 1000, OutcomeStatus.BOUNDARY, 123.4, 150.5)))
    on_msg(2, _trace_msg(2, data=[1000, 99, 1.0, 1.0, 0.0]))  # malformed: counted, ignored
    assert ex.report_errors == 1 and f.pieces[1000].traced_m == pytest.approx(123.4)
    assert not f.done
    on_msg(2, mavlink.MAVLink_mission_item_reached_message(2))
    assert f.done
    r = ex.telemetry.end(v)
    assert r.vehicle == 1
    # in time order; the late one has the phase reported for its time
    assert list(r.samples.phase) == [Phase.SEARCH, Phase.SEARCH, Phase.TRACE]
    np.testing.assert_allclose(r.samples.x_m, [1.0, 1.5, 2.0], atol=0.02)
    assert r.traced_m == pytest.approx(123.4)
    assert r.outcomes[0].status == OutcomeStatus.BOUNDARY
    assert r.outcomes[0].flown_m == pytest.approx(150.5)
    assert r.sim_s == pytest.approx(0.1)
    # vehicle 1 was not flying: its sample is kept for later, not lost
    assert len(ex.pending_samples()) == 1
    # a lost vehicle is given up (its work goes to the others); losing all fails the run
    router.handlers["event"](VehicleLost(2, 21.0))
    assert ex.vehicles[2].lost == "no heartbeat for 21 s"
    assert ex.losses[0]["sysid"] == 2
    ex.vehicle_losses.check_lost()
    router.handlers["event"](VehicleLost(1, 6.0))
    with pytest.raises(VehicleTimeout, match="every vehicle lost: vehicle 1 lost: no heartbeat "
                                             "for 6 s; vehicle 2 lost: no heartbeat for 21 s"):
        ex.vehicle_losses.check_lost()


def test_a_vehicle_without_phase_reports_gets_the_phase_of_its_item() -> None:
    """A stock autopilot flies a contour as waypoints: the first is reached in transit, the
    legs after it are along the (estimated) contour; its outcome is accounted by item."""
    m = _mission()
    router = FakeRouter()
    ex = MavlinkExecutor(SimpleNamespace(router=router), m, [1])  # type: ignore[arg-type]
    route = ((10.0, 0.0), (20.0, 0.0), (20.0, 10.0))
    tasks = [Waypoint(5.0, 0.0), TraceTask(50.0, 10.0, 0.0, 10.0, 0.0, 1000, route_m=route)]
    plan = plan_mission(m.origin, tasks, 30.0, style=TaskStyle.WAYPOINTS, tolerance_m=0.1,
                        end="none")
    assert plan.task_seqs == [(2, 2), (3, 5)]
    v = ex.vehicles[1]
    v.items = plan.items
    f = ex.telemetry.begin(v, tasks, plan)
    v.status = "flying"
    on_msg, on_sample = router.handlers["message"], router.handlers["sample"]
    for seq, ms, x, y in ((2, 1000, 5.0, 0.0), (3, 1100, 10.0, 0.0), (4, 1200, 20.0, 0.0),
                          (5, 1300, 20.0, 10.0)):
        on_msg(1, mavlink.MAVLink_mission_current_message(seq, 6, 2, 1))
        on_sample(_sample(m.origin, 1, ms, x, y, 1.0))
        on_msg(1, mavlink.MAVLink_mission_item_reached_message(seq))
    assert f.done
    r = ex.telemetry.end(v)
    assert list(r.samples.phase) == [Phase.TRANSIT, Phase.TRANSIT, Phase.TRACE, Phase.TRACE]
    assert [o.status for o in r.outcomes] == ["reached", "reached"]
    # flown along the contour: the legs to items 4 and 5 (10 m each)
    assert r.outcomes[1].traced_m == pytest.approx(20.0, abs=0.05)
    assert r.outcomes[1].flown_m == pytest.approx(25.0, abs=0.05)
    assert r.traced_m == pytest.approx(20.0, abs=0.05)


def _flying(ex: Any, v: Any, tasks: list[Any], survey: bool = False) -> Any:
    plan = plan_mission(ex.origin, tasks, 30.0, end="none")
    v.items = plan.items
    f = ex.telemetry.begin(v, tasks, plan, survey=survey)
    v.status = "flying"
    return f


def test_a_survey_flights_samples_are_survey_whatever_the_vehicle_reports() -> None:
    """The vehicle flies waypoints and says TRANSIT; the station flies them as its survey:
    every sample of the flight is SURVEY when it is handed over (report or error path)."""
    m = _mission()
    router = FakeRouter()
    ex = MavlinkExecutor(SimpleNamespace(router=router), m, [1, 2])  # type: ignore[arg-type]
    on_msg, on_sample = router.handlers["message"], router.handlers["sample"]
    flights = {s: _flying(ex, ex.vehicles[s], [Waypoint(5.0, 0.0), Waypoint(5.0, 5.0)],
                          survey=True) for s in (1, 2)}
    assert all(f.survey for f in flights.values())
    for sysid in (1, 2):
        on_msg(sysid, rx(mavlink.MAVLink_named_value_int_message(900, b"PHASE",
                                                                 int(Phase.TRANSIT)), sysid))
        for k in range(5):
            on_sample(_sample(m.origin, sysid, 1000 + 100 * k, float(k), 0.0, 1.0))
    r = ex.telemetry.end(ex.vehicles[1])
    assert len(r.samples) == 5 and set(r.samples.phase.tolist()) == {int(Phase.SURVEY)}
    pending = ex.pending_samples()  # vehicle 2's flight is still in progress
    assert len(pending) == 5 and set(pending.phase.tolist()) == {int(Phase.SURVEY)}
    # the next flight is no survey: the vehicle's phases again
    _flying(ex, ex.vehicles[1], [Waypoint(9.0, 0.0)])
    on_sample(_sample(m.origin, 1, 2000, 9.0, 0.0, 1.0))
    assert ex.telemetry.end(ex.vehicles[1]).samples.phase.tolist() == [int(Phase.TRANSIT)]


def test_a_sample_phase_is_decided_once_when_its_flight_ends(monkeypatch: Any) -> None:
    """Nothing is guessed on arrival: each sample's phase is decided once, at the end, with
    everything the vehicle said, a PHASE report that came after its samples included."""
    from econdor_gcs.station import flight as flight_module

    decided: list[int] = []
    real = flight_module.decide_phases

    def counting(t_ms: Any, *args: Any, **kwargs: Any) -> Any:
        decided.append(len(t_ms))
        return real(t_ms, *args, **kwargs)

    monkeypatch.setattr(flight_module, "decide_phases", counting)
    m = _mission()
    router = FakeRouter()
    ex = MavlinkExecutor(SimpleNamespace(router=router), m, [1])  # type: ignore[arg-type]
    on_msg, on_sample = router.handlers["message"], router.handlers["sample"]
    journal: list[Any] = []
    ex.telemetry.on_rows = lambda v, rows: journal.extend(rows)
    v = ex.vehicles[1]
    _flying(ex, v, [TraceTask(50.0, 10.0, 0.0, 10.0, 0.0, 1000)])
    on_msg(1, mavlink.MAVLink_mission_current_message(2, 3, 2, 1))
    on_msg(1, rx(mavlink.MAVLink_named_value_int_message(900, b"PHASE", int(Phase.SEARCH)), 1))
    for k in range(6):
        on_sample(_sample(m.origin, 1, 1000 + 100 * k, float(k), 0.0, 1.0))
    ex.status_rows()  # converts the batch (the journal shows it), decides nothing
    assert len(journal) == 6 and decided == []
    # the change at 1300 ms comes after the samples it covers (reordered on the link)
    on_msg(1, rx(mavlink.MAVLink_named_value_int_message(1300, b"PHASE", int(Phase.TRACE)), 1))
    r = ex.telemetry.end(v)
    assert decided == [6]
    assert r.samples.phase.tolist() == [int(Phase.SEARCH)] * 3 + [int(Phase.TRACE)] * 3


def test_a_late_sample_of_a_vehicle_without_phases_is_in_the_item_it_was_taken_in() -> None:
    """A stock vehicle reports no phases: a sample that arrives after later ones is in the
    mission item of the sample before it by time, whatever item is current on arrival."""
    m = _mission()
    router = FakeRouter()
    ex = MavlinkExecutor(SimpleNamespace(router=router), m, [1])  # type: ignore[arg-type]
    route = ((10.0, 0.0), (20.0, 0.0), (20.0, 10.0))
    tasks = [TraceTask(50.0, 10.0, 0.0, 10.0, 0.0, 1000, route_m=route)]
    plan = plan_mission(m.origin, tasks, 30.0, style=TaskStyle.WAYPOINTS, tolerance_m=0.1,
                        end="none")
    v = ex.vehicles[1]
    v.items = plan.items
    ex.telemetry.begin(v, tasks, plan)
    v.status = "flying"
    on_msg, on_sample = router.handlers["message"], router.handlers["sample"]
    on_msg(1, mavlink.MAVLink_mission_current_message(2, 5, 2, 1))  # to the contour's start
    on_sample(_sample(m.origin, 1, 1000, 2.0, 0.0, 1.0))
    on_sample(_sample(m.origin, 1, 1200, 8.0, 0.0, 1.0))
    on_msg(1, mavlink.MAVLink_mission_current_message(3, 5, 2, 1))  # along the contour
    on_sample(_sample(m.origin, 1, 1400, 14.0, 0.0, 1.0))
    on_sample(_sample(m.origin, 1, 1100, 5.0, 0.0, 1.0))  # late: taken in transit
    r = ex.telemetry.end(v)
    np.testing.assert_allclose(r.samples.x_m, [2.0, 5.0, 8.0, 14.0], atol=0.02)
    assert r.samples.phase.tolist() == [int(Phase.TRANSIT)] * 3 + [int(Phase.TRACE)]


def test_the_survey_flag_reaches_the_flight_through_the_upload() -> None:
    m = _mission()
    ex = MavlinkExecutor(SimpleNamespace(router=FakeRouter()), m, [1])  # type: ignore[arg-type]
    _scripted_uploads(ex, [None, None])
    v = ex.vehicles[1]
    asyncio.run(ex.vehicle_missions.plan_and_upload(v, [Waypoint(5.0, 0.0)], 0, 0,
                                                    survey=True))
    assert v.flight is not None and v.flight.survey
    asyncio.run(ex.vehicle_missions.plan_and_upload(v, [Waypoint(5.0, 0.0)], 1, 0))
    assert v.flight is not None and not v.flight.survey


def test_returning_vehicle_has_landed_when_its_state_says_so() -> None:
    m = _mission()
    router = FakeRouter()
    ex = MavlinkExecutor(SimpleNamespace(router=router), m, [1])  # type: ignore[arg-type]
    v = ex.vehicles[1]
    f = ex.telemetry.begin(v, [])
    on_msg = router.handlers["message"]
    on_msg(1, mavlink.MAVLink_statustext_message(6, b"landed, disarmed", 0, 0))
    assert not f.landed  # words are not state
    v.status = "returning"
    on_msg(1, mavlink.MAVLink_extended_sys_state_message(0, mavlink.MAV_LANDED_STATE_IN_AIR))
    assert not f.landed
    on_msg(1, mavlink.MAVLink_extended_sys_state_message(0, mavlink.MAV_LANDED_STATE_ON_GROUND))
    assert f.landed and v.status == "landed"


def test_mission_complete_state_ends_a_flight_without_item_reached() -> None:
    m = _mission()
    router = FakeRouter()
    ex = MavlinkExecutor(SimpleNamespace(router=router), m, [1, 2])  # type: ignore[arg-type]
    v = ex.vehicles[1]
    v.items = build_mission(m.origin, [Waypoint(1, 1), Waypoint(2, 2)], 30.0, end="none")
    f = ex.telemetry.begin(v, [Waypoint(1, 1), Waypoint(2, 2)])
    on_msg = router.handlers["message"]
    # a stale "complete" before our MISSION_START was accepted does not count
    on_msg(1, mavlink.MAVLink_mission_current_message(3, 4, mavlink.MISSION_STATE_COMPLETE, 0))
    assert not f.done
    v.status = "flying"
    on_msg(1, mavlink.MAVLink_mission_current_message(3, 4, mavlink.MISSION_STATE_COMPLETE, 0))
    assert f.done


def test_a_vehicle_that_never_finishes_its_item_is_lost() -> None:
    """Heartbeats alone do not keep a vehicle in service: an item that takes longer than
    its limit (3x its planned length at cruise speed + 60 s, in the vehicle's own time)
    makes it lost, and it is told to return."""
    import asyncio

    m = _mission()
    router = FakeRouter()
    returned: list[int] = []

    async def return_to_launch(sysid: int) -> None:
        returned.append(sysid)

    router.return_to_launch = return_to_launch  # type: ignore[attr-defined]
    ex = MavlinkExecutor(SimpleNamespace(router=router), m, [1, 2])  # type: ignore[arg-type]
    tr = TraceTask(50.0, 10.0, 10.0, 10.0, 300.0, 1000)
    v = ex.vehicles[1]
    v.items = build_mission(m.origin, [tr], 30.0, end="none")
    ex.telemetry.begin(v, [tr])
    router.vehicles[1].time_boot_ms = 5000
    router.handlers["message"](1, mavlink.MAVLink_mission_current_message(2, 3, 2, 1))
    limit_s = ex.vehicle_losses.item_limit_s(v)
    region = m.region
    expected = 3 * (2 * (region.width_m + region.height_m) + 2 * math.pi * 10 + 300) / \
        m.vehicles.speed_mps + 60
    assert limit_s == pytest.approx(expected)

    async def main() -> None:
        router.vehicles[1].time_boot_ms = 5000 + int(1000 * limit_s) - 100
        ex.vehicle_losses.check_progress([v])
        assert v.lost is None
        router.vehicles[1].time_boot_ms = 5000 + int(1000 * limit_s) + 100
        ex.vehicle_losses.check_progress([v])
        async with asyncio.timeout(5.0):  # the return to launch runs as a task of its own
            while not returned:
                await asyncio.sleep(0)

    asyncio.run(main())
    assert v.lost is not None and v.lost.startswith("mission item 2 not finished within")
    assert returned == [1]


def test_the_station_thread_alone_touches_vehicle_state() -> None:
    """The display's snapshot and the DFC's positions are made on the station's loop thread,
    whichever thread asks (the render used to convert samples on its own thread)."""
    import threading

    from econdor_gcs.station.loop import Station

    station = Station("udpin:127.0.0.1:0")
    station.start()
    try:
        ex = MavlinkExecutor(station, _mission(), [])
        seen: list[threading.Thread] = []
        real = ex._status_rows

        def spy() -> list[dict[str, Any]]:
            seen.append(threading.current_thread())
            return real()

        ex._status_rows = spy  # type: ignore[method-assign]
        worker = threading.Thread(target=ex.status_rows)
        worker.start()
        worker.join(5)
        ex.status_rows()
        assert [t.name for t in seen] == ["econdor-gcs", "econdor-gcs"]
        assert ex.positions() == []
    finally:
        station.close()


def test_a_landed_vehicle_is_not_late_while_the_others_come_home() -> None:
    """On the way home the first vehicle down waits for the others; its clock runs on, but
    it finished: no time limit applies to it (it was declared lost under load before)."""
    m = _mission()
    router = FakeRouter()
    ex = MavlinkExecutor(SimpleNamespace(router=router), m, [1, 2])  # type: ignore[arg-type]
    v = ex.vehicles[1]
    f = ex.telemetry.begin(v, [])
    v.item_since_ms = 0
    f.landed = True
    router.vehicles[1].time_boot_ms = 10**7  # hours of its time later
    ex.vehicle_losses.check_progress([v])
    assert v.lost is None


def _scripted_uploads(ex: Any, answers: list[int | None]) -> list[list[int]]:
    """Replace the executor's upload with one that answers each attempt from ``answers``
    (a MAV_MISSION_RESULT refusing item 3, or None: accepted); returns the commands sent."""
    sent: list[list[int]] = []

    async def upload(v: Any, items: list[Any]) -> None:
        sent.append([it.command for it in items])
        result = answers[len(sent) - 1]
        if result is not None:
            raise MissionRejected(f"vehicle {v.sysid} rejected mission item 3", result, 3,
                                  items[3].command)

    ex.vehicle_missions.upload = upload
    return sent


def test_a_lost_refusal_of_a_contour_item_restarts_the_upload() -> None:
    """A stock vehicle's UNSUPPORTED for the contour item is lost; the item sent again meets
    no transfer (INVALID_SEQUENCE): the upload starts again, meets the refusal, and the
    pieces go as waypoints."""
    m = _mission()
    ex = MavlinkExecutor(SimpleNamespace(router=FakeRouter()), m, [1])  # type: ignore[arg-type]
    sent = _scripted_uploads(ex, [mavlink.MAV_MISSION_INVALID_SEQUENCE,
                                  mavlink.MAV_MISSION_UNSUPPORTED,
                                  mavlink.MAV_MISSION_ERROR, None])
    route = ((10.0, 0.0), (20.0, 0.0), (20.0, 10.0))
    v = ex.vehicles[1]
    asyncio.run(ex.vehicle_missions.plan_and_upload(
        v, [TraceTask(50.0, 10.0, 0.0, 10.0, 0.0, 1000, route_m=route)], 1, 0))
    trace, wp = mavlink.MAV_CMD_WAYPOINT_USER_1, mavlink.MAV_CMD_NAV_WAYPOINT
    assert [trace in c for c in sent] == [True, True, False, False]
    assert all(c[3:] == [wp] * 3 for c in sent[2:])
    assert v.style == TaskStyle.WAYPOINTS
    assert v.flight is not None and v.flight.style == TaskStyle.WAYPOINTS


def test_a_refused_sensor_lag_item_sends_the_pieces_as_waypoints() -> None:
    """A stock vehicle meets the sensor lag item before the contour item it goes with and
    refuses it (UNSUPPORTED) as it would the contour item: the pieces go as waypoints."""
    m = _mission()
    ex = MavlinkExecutor(SimpleNamespace(router=FakeRouter()), m, [1])  # type: ignore[arg-type]
    sent = _scripted_uploads(ex, [mavlink.MAV_MISSION_UNSUPPORTED, None])
    route = ((10.0, 0.0), (20.0, 0.0), (20.0, 10.0))
    v = ex.vehicles[1]
    asyncio.run(ex.vehicle_missions.plan_and_upload(
        v, [TraceTask(50.0, 10.0, 0.0, 10.0, 0.0, 1000, route_m=route, sensor_lag_s=0.5)],
        1, 0))
    trace = mavlink.MAV_CMD_WAYPOINT_USER_1
    assert sent[0][3:] == [SENSOR_LAG_COMMAND, trace]
    assert sent[1][3:] == [mavlink.MAV_CMD_NAV_WAYPOINT] * 3
    assert v.style == TaskStyle.WAYPOINTS


def test_an_upload_refused_again_and_again_fails() -> None:
    m = _mission()
    ex = MavlinkExecutor(SimpleNamespace(router=FakeRouter()), m, [1])  # type: ignore[arg-type]
    sent = _scripted_uploads(ex, [mavlink.MAV_MISSION_INVALID_SEQUENCE] * 5)
    with pytest.raises(MissionRejected, match="rejected mission item 3"):
        asyncio.run(ex.vehicle_missions.plan_and_upload(ex.vehicles[1], [Waypoint(5.0, 0.0)] * 3, 1, 0))
    assert len(sent) == UPLOAD_ATTEMPTS


def test_a_mission_upload_that_never_finishes_says_when_an_ardupilot_holds_part_of_it() -> None:
    """Every attempt runs out of answers while the vehicle heartbeats; the last error says
    so, and, when the router noted that the vehicle (an ArduPilot) took part of the upload
    over its mission, says that too."""
    router = FakeRouter()
    attempts: list[int] = []

    async def upload_mission(sysid: int, items: Any, **kw: Any) -> int:
        attempts.append(sysid)
        raise VehicleTimeout(f"vehicle {sysid} did not answer mission upload (no request "
                             "after item 2)")

    router.upload_mission = upload_mission  # type: ignore[attr-defined]
    ex = MavlinkExecutor(SimpleNamespace(router=router), _mission(), [1])  # type: ignore[arg-type]
    v = ex.vehicles[1]
    items = build_mission(_mission().origin, [Waypoint(5.0, 0.0)], 30.0)
    with pytest.raises(VehicleTimeout) as clean:
        asyncio.run(ex.vehicle_missions.upload(v, items))
    assert len(attempts) == UPLOAD_ATTEMPTS and "holds part" not in str(clean.value)
    router.vehicles[1].partial_missions.add(mavlink.MAV_MISSION_TYPE_MISSION)
    with pytest.raises(VehicleTimeout, match="it holds part of this mission over the one "
                                             "before, as ArduPilot stores items as they come"):
        asyncio.run(ex.vehicle_missions.upload(v, items))
