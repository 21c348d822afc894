"""``econdor upload``: verify-after-upload and --start against both personalities."""

from __future__ import annotations

import argparse
import dataclasses
import math
import tempfile
from pathlib import Path

import pytest

from econdor.cli import main
from econdor_gcs.app.export import export_cli
from econdor_gcs.app.upload import compare_items
from econdor_gcs.files.autopilot_files import read_mission_file
from econdor_gcs.link.autopilots import AutopilotKind
from econdor_gcs.link.codec import mavlink
from econdor_gcs.link.items import waypoint_item
from tests.helpers.vehicles import DEMO, free_port, inproc_vehicle, wait_for

ORIGIN_ITEMS = [waypoint_item(0, 47.397742, 8.545594, 0.0),
                waypoint_item(1, 47.3978, 8.5457, 30.123)]


def test_compare_allows_ardupilot_habits_and_nothing_else():
    sent = ORIGIN_ITEMS
    ap_back = [dataclasses.replace(sent[0], frame=0, x=473000000, z=512.3),
               dataclasses.replace(sent[1], frame=3, z=30.12, autocontinue=1, current=0)]
    assert compare_items(sent, ap_back, AutopilotKind.ARDUPILOT) == []
    diffs = compare_items(sent, ap_back, AutopilotKind.PX4)
    assert {(d.seq, d.field) for d in diffs} == {(0, "frame"), (0, "x"), (0, "z"), (1, "z")}
    # a different position, command or param is a difference for everyone
    moved = [sent[0], dataclasses.replace(sent[1], y=sent[1].y + 1, param1=2.0)]
    found = compare_items(sent, moved, AutopilotKind.ARDUPILOT)
    assert [str(d) for d in found] == ["item 1 param1: sent 0.0, got back 2.0",
                                       f"item 1 y: sent {sent[1].y}, got back {sent[1].y + 1}"]
    assert compare_items(sent, sent[:1])[0].field == "count"
    # float32 on the wire and NaN params are the same value
    nan = [dataclasses.replace(sent[1], param4=math.nan, z=0.1)]
    back = [dataclasses.replace(sent[1], param4=math.nan, z=0.10000000149011612)]
    assert compare_items(nan, back, AutopilotKind.PX4) == []


def exported(tmp: Path, fmt: str = "wpl", style: str = "waypoints") -> Path:
    out = tmp / f"m.{'waypoints' if fmt == 'wpl' else 'plan'}"
    export_cli(argparse.Namespace(
        source=DEMO, out=out, format=fmt, style=style, alt_m=15.0, speed_mps=10.0,
        tolerance_m=1.0, vehicles=1, spacing_m=None, fence_margin_m=10.0, iteration=None,
        vehicle=None))
    return out


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_upload_start_round_trips_and_flies_on_both_personalities(tmp_path, capsys, autopilot):
    path = exported(tmp_path, "plan")
    mfile = read_mission_file(path)
    port = free_port()
    with inproc_vehicle(connect=f"udpout:127.0.0.1:{port}", speedup=200.0, autopilot=autopilot,
                        companion=False, prearm_s=1.0) as v:
        code = main(["upload", str(path), "--connect", f"udpin:127.0.0.1:{port}", "--start",
                     "--timeout", "10"])
        out = capsys.readouterr()
        assert code == 0, out.err
        assert f"vehicle 1 ({autopilot}): uploaded and verified {len(mfile.items)} mission " \
               f"items, 4 fence items, 1 rally item" in out.out
        assert "1 rally items" not in out.out
        assert ("item 0 replaced by its home" in out.out) == (autopilot == "ardupilot")
        assert "mission started" in out.out
        # the vehicle stored the fence and rally point of the plan
        assert len(v.server.stores[mavlink.MAV_MISSION_TYPE_FENCE]) == 4
        assert len(v.server.stores[mavlink.MAV_MISSION_TYPE_RALLY]) == 1
        # and flies the mission to its end: the last item is RTL, it lands and disarms
        last = len(mfile.items) - 1
        wait_for(lambda: v.armed or v.state.in_air, 5, "takeoff")
        wait_for(lambda: v.server.current_seq == last and not v.armed, 30, "the end of it")
        assert v.state.mission_complete
        assert math.hypot(v.body.x_m, v.body.y_m) < 2.0 and not v.state.in_air


def test_upload_refusals_and_differences_are_one_line(tmp_path, capsys):
    trace = exported(tmp_path, "wpl", style="waypoints")
    port = free_port()
    with inproc_vehicle(connect=f"udpout:127.0.0.1:{port}", autopilot="ardupilot",
                        companion=False) as v:
        # an autopilot that stores something else than it was sent
        real = v.server.reported
        v.server.reported = lambda it: dataclasses.replace(real(it), z=it.z + 1.0) \
            if it.seq == 3 else real(it)
        assert main(["upload", str(trace), "--connect", f"udpin:127.0.0.1:{port}",
                     "--timeout", "10"]) == 1
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0
        assert "vehicle 1: the mission read back differs from the file: item 3 z: sent 15.0, " \
               "got back 16.0" in err
    # a stock autopilot refuses contour items: the error says what to do, and the items
    # before the refused one, which ArduPilot had stored over its old mission, are cleared
    with inproc_vehicle(connect=f"udpout:127.0.0.1:{port}", autopilot="ardupilot",
                        companion=False) as v:
        contour = tmp_path / "c.waypoints"
        contour.write_text(
            "QGC WPL 110\n0\t1\t3\t16\t0\t0\t0\t0\t47.397742\t8.545594\t0\t1\n"
            "1\t0\t3\t22\t0\t0\t0\t0\t47.397742\t8.545594\t20\t1\n"
            "2\t0\t3\t31000\t42\t10\t0\t3\t47.3979\t8.5459\t20\t1\n")
        assert main(["upload", str(contour), "--connect", f"udpin:127.0.0.1:{port}",
                     "--timeout", "10"]) == 1
        err = capsys.readouterr().err.strip()
        assert err == ("econdor: error: vehicle 1 rejected mission item 2: "
                       "MAV_MISSION_UNSUPPORTED (a stock autopilot flies contours as "
                       "waypoints: export with --style waypoints); its mission was cleared "
                       "(ArduPilot had stored part of this upload over what it had)")
        assert v.server.mission == [] and v.server.counters["uploads"] == 0
        # a mission without a home item would lose its first item on ArduPilot
        headless = tmp_path / "h.waypoints"
        headless.write_text("QGC WPL 110\n"
                            "0\t1\t3\t22\t0\t0\t0\t0\t47.397742\t8.545594\t20\t1\n")
        assert main(["upload", str(headless), "--connect", f"udpin:127.0.0.1:{port}",
                     "--timeout", "10"]) == 1
        assert "replaces item 0 with its home, and item 0 of this mission is command 22" in \
            capsys.readouterr().err


def _stall_after_two_items(v, mtype: int | None = None):
    """Make vehicle ``v`` ask for items 0 and 1 of an upload (of ``mission_type`` ``mtype``;
    any if None) and then send nothing the station waits for; returns its own asking."""
    asked = v.server._request

    def stall(up):
        if len(up.items) < 2 or (mtype is not None and up.mission_type != mtype):
            return asked(up)
        return mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, b"busy", 0, 0)

    v.server._request = stall
    return asked


def _interrupt_once_two_items_are_taken(v, mtype: int | None = None):
    """Ctrl-C (in the main thread, where the command runs) once ``v`` holds two items of an
    upload still running; returns the thread, to join."""
    import _thread
    import threading

    def interrupt():
        wait_for(lambda: (up := v.server.upload) is not None and len(up.items) == 2
                 and (mtype is None or up.mission_type == mtype), 20,
                 "the first two items taken")
        _thread.interrupt_main()

    t = threading.Thread(target=interrupt, daemon=True)
    t.start()
    return t


@pytest.mark.parametrize("what", ["mission", "rally points"])
def test_an_upload_interrupted_part_way_leaves_an_ardupilot_no_mix_of_two_missions(
        tmp_path, capsys, what):
    """Ctrl-C while ArduPilot takes the items (of the mission, or of the rally points, which
    it also writes as they come): it has written the first ones over what it had (and would
    go on asking for 8 s); the station clears them and says so."""
    import json

    path = exported(tmp_path, "plan")
    doc = json.loads(path.read_text())
    doc["rallyPoints"]["points"] *= 3  # three rally points
    path.write_text(json.dumps(doc))
    mtype = (mavlink.MAV_MISSION_TYPE_MISSION if what == "mission"
             else mavlink.MAV_MISSION_TYPE_RALLY)
    port = free_port()
    with inproc_vehicle(connect=f"udpout:127.0.0.1:{port}", autopilot="ardupilot",
                        companion=False) as v:
        _stall_after_two_items(v, mtype)
        t = _interrupt_once_two_items_are_taken(v, mtype)
        code = main(["upload", str(path), "--connect", f"udpin:127.0.0.1:{port}",
                     "--timeout", "10"])
        t.join()
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 130
        verb = "was" if what == "mission" else "were"
        assert err == [f"econdor: vehicle 1: its {what} {verb} cleared (ArduPilot had stored "
                       "part of this upload over what it had)", "econdor: interrupted"]
        assert v.server.stores[mtype] == [] and v.server.upload is None
        if what == "rally points":  # the mission and the fence went up whole before
            assert v.server.mission and v.server.stores[mavlink.MAV_MISSION_TYPE_FENCE]


def test_an_upload_left_part_way_on_px4_is_cancelled_so_the_next_one_is_taken():
    """PX4 refuses every new count while it takes an upload (MAV_MISSION_ERROR, "busy"):
    the station's MISSION_ACK(OPERATION_CANCELLED) for the upload it gave up frees it at
    once; when that cancel is lost, the next upload takes the vehicle's request for the
    old transfer's item as the sign of it, cancels it and counts again."""
    from econdor_gcs.errors import VehicleTimeout
    from econdor_gcs.station.loop import Station

    port = free_port()
    items = read_mission_file(exported(Path(tempfile.mkdtemp()), "wpl")).items
    with inproc_vehicle(connect=f"udpout:127.0.0.1:{port}", autopilot="px4") as v:
        station = Station(f"udpin:127.0.0.1:{port}", heartbeat_timeout_s=10.0)
        try:
            station.start()
            router = station.router
            station.call(router.wait_for_vehicles([1], 10.0))

            def upload(mission=items):
                return station.call(router.upload_mission(1, list(mission), timeout_s=0.3,
                                                          retries=2))

            send = router.send
            for lose_the_cancel in (False, True):
                asked = _stall_after_two_items(v)
                if lose_the_cancel:
                    router.send = lambda sysid, msg: None if msg.get_type() == "MISSION_ACK" \
                        else send(sysid, msg)
                with pytest.raises(VehicleTimeout):
                    upload()
                router.send = send
                v.server._request = asked
                if not lose_the_cancel:
                    wait_for(lambda: v.server.upload is None, 5, "the cancel taken")
                else:
                    assert v.server.upload is not None  # still busy with the old transfer
                # another mission: none of its items may complete the transfer left
                other = items[:-1]
                assert upload(other) == len(other)
                assert [it.seq for it in v.server.mission] == [it.seq for it in other]
        finally:
            station.close()


def test_an_upload_interrupted_while_an_ardupilot_flies_its_mission_says_it_is_left_mixed(
        tmp_path, capsys):
    """In flight (AUTO), ArduPilot refuses to clear its mission: after an upload interrupted
    part-way the station says the mission is a mix and must be cleared before it is flown."""
    path = exported(tmp_path, "wpl")
    port = free_port()
    with inproc_vehicle(connect=f"udpout:127.0.0.1:{port}", autopilot="ardupilot",
                        companion=False, prearm_s=1.0, speedup=5.0) as v:
        connect = ["--connect", f"udpin:127.0.0.1:{port}", "--timeout", "10"]
        assert main(["upload", str(path), *connect, "--start"]) == 0
        wait_for(lambda: v.state.mission_active and v.state.alt_rel_m > 5.0, 20, "in flight")
        capsys.readouterr()
        _stall_after_two_items(v)
        t = _interrupt_once_two_items_are_taken(v)
        assert main(["upload", str(path), *connect]) == 130
        t.join()
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 2 and err[1] == "econdor: interrupted"
        assert err[0].startswith("econdor: vehicle 1: its mission is now part this upload, "
                                 "part what it had (ArduPilot stores items as they come), "
                                 "and clearing failed (")
        assert "MAV_MISSION_ERROR" in err[0] and err[0].endswith("clear it before flying")
        assert v.state.mission_active and len(v.server.mission) == len(read_mission_file(
            path).items)
