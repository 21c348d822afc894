"""Runs in a row through a bad link: does every run complete and keep every sample?

    python bench/lossy_link.py [--runs 10] [--relay econdor,independent]
                               [--drop 0.2] [--duplicate 0.1] [--reorder 0.1]
                               [--outage START:SECONDS] [--mission missions/demo.yaml]
                               [--vehicles 3] [--speedup X] [--keep DIR] [--seed S]

Each run is what an operator would do by hand: ``sim-vehicle`` processes (PX4 habits, the
tracer on board) sending to a relay, and ``econdor run --connect`` behind it, each in its own
process. The relay is either ``econdor relay`` or the small one in this file (``relay``
sub-command), written independently of ours on purpose: its reordering delays a datagram by a
random 10-100 ms (ours holds one back behind the next), so a fault our relay happens not to
make is still met. ``--outage START:SECONDS`` also cuts the link both ways for SECONDS,
START seconds after the first datagram.

Per run it prints: the exit status, iterations, vehicles given up (every vehicle here is
healthy: any given up is a failure), and samples: what the vehicles took (their own exit
lines), what reached the station (distinct FIELD measurements in the tlog, resends
included: the station places a sample whose own GLOBAL_POSITION_INT was lost between the
positions around it, so a measurement that arrived is a sample that reached it) and what the
run directory kept (``samples.csv``); then ``resent``, the
commands sent again because neither an answer nor the vehicle's telemetry showed them done
(a resent MISSION_START would fly a mission again), ``left``, the flights a vehicle left on
its own (its GCS failsafe after 5 s without the station's heartbeat), and the achieved
speed-up. A run counts as good when it exits 0, gives nobody up, and keeps every sample
that reached the station.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import heapq
import json
import os
import random
import re
import selectors
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


# --------------------------------------------------------------------------------------------
# an independent relay (not econdor_gcs.link.relay)


@dataclass
class _Held:
    due: float
    seq: int
    sock: socket.socket
    data: bytes
    addr: tuple[str, int] | None

    def __lt__(self, other: _Held) -> bool:
        return (self.due, self.seq) < (other.due, other.seq)


def serve_relay(listen_port: int, to_port: int, drop: float, duplicate: float,
                reorder: float, seed: int, outage: tuple[float, float] | None) -> int:
    """Relay UDP between clients of 127.0.0.1:``listen_port`` and 127.0.0.1:``to_port``.

    Each client gets its own socket towards ``to_port`` (so the station sees one address per
    vehicle). Every datagram, each way: lost with ``drop``, sent twice with ``duplicate``,
    delayed 10-100 ms with ``reorder``; during the outage, every datagram is lost."""
    rng = random.Random(seed)
    sel = selectors.DefaultSelector()
    lsock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    lsock.bind(("127.0.0.1", listen_port))
    lsock.setblocking(False)
    sel.register(lsock, selectors.EVENT_READ, None)
    up: dict[tuple[str, int], socket.socket] = {}
    held: list[_Held] = []
    counts: Counter[str] = Counter()
    first: list[float] = []
    stop: list[int] = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    print(f"relay: listening on udpin:127.0.0.1:{lsock.getsockname()[1]}", file=sys.stderr,
          flush=True)
    seq = 0

    def emit(sock: socket.socket, data: bytes, addr: tuple[str, int] | None) -> None:
        with contextlib.suppress(OSError):
            if addr is None:
                sock.send(data)
            else:
                sock.sendto(data, addr)

    def relay(sock: socket.socket, data: bytes, addr: tuple[str, int] | None, way: str) -> None:
        nonlocal seq
        now = time.monotonic()
        if not first:
            first.append(now)
        counts[f"{way}_in"] += 1
        if outage is not None and outage[0] <= now - first[0] < outage[0] + outage[1]:
            counts[f"{way}_blacked_out"] += 1
            return
        if rng.random() < drop:
            counts[f"{way}_dropped"] += 1
            return
        copies = 2 if rng.random() < duplicate else 1
        counts[f"{way}_duplicated"] += copies - 1
        for _ in range(copies):
            if rng.random() < reorder:
                counts[f"{way}_delayed"] += 1
                seq += 1
                heapq.heappush(held, _Held(now + rng.uniform(0.01, 0.1), seq, sock, data, addr))
            else:
                emit(sock, data, addr)

    while not stop:
        timeout = max(0.0, held[0].due - time.monotonic()) if held else 0.2
        for key, _ in sel.select(min(timeout, 0.2)):
            sock = key.fileobj
            assert isinstance(sock, socket.socket)
            while True:
                try:
                    data, addr = sock.recvfrom(65535)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    continue  # ICMP unreachable: nobody there yet
                if key.data is None:  # from a client, towards the station
                    s = up.get(addr)
                    if s is None:
                        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                        s.connect(("127.0.0.1", to_port))
                        s.setblocking(False)
                        sel.register(s, selectors.EVENT_READ, addr)
                        up[addr] = s
                    relay(s, data, None, "up")
                else:  # from the station, back to its client
                    relay(lsock, data, key.data, "down")
        now = time.monotonic()
        while held and held[0].due <= now:
            h = heapq.heappop(held)
            emit(h.sock, h.data, h.addr)
    print("relay: " + " ".join(f"{k} {v}" for k, v in sorted(counts.items())), file=sys.stderr,
          flush=True)
    return 0


# --------------------------------------------------------------------------------------------
# one run


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop(proc: subprocess.Popen[bytes]) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


def reached_station(tlog: Path, sysids: list[int]) -> dict[int, int]:
    """Distinct samples (``FIELD`` measurements, one per ``time_boot_ms``) that reached the
    station, per system id, from its tlog. Their positions are not required: the station
    places a sample between the positions around it when its own was lost
    (:mod:`econdor_gcs.link.pairing`), so counting only complete FIELD + GLOBAL_POSITION_INT
    pairs would call samples "not reached" that the station rightly kept."""
    from econdor_gcs.link.tlog import read_tlog

    val: dict[int, set[int]] = {s: set() for s in sysids}
    for m in read_tlog(tlog):
        s = m.get_srcSystem()
        if s in val and m.get_type() == "NAMED_VALUE_FLOAT" and m.name.rstrip("\x00") == "FIELD":
            val[s].add(m.time_boot_ms)
    return {s: len(val[s]) for s in sysids}


def kept(run_dir: Path, sysids: list[int]) -> dict[int, int]:
    """Rows of samples.csv per system id (vehicle index i is system id ``sysids[i]``)."""
    path = run_dir / "samples.csv"
    if not path.exists():
        return {s: 0 for s in sysids}
    with path.open(newline="") as f:
        per_index = Counter(int(r["vehicle"]) for r in csv.DictReader(f))
    return {s: per_index[i] for i, s in enumerate(sysids)}


@dataclass
class RunResult:
    relay: str
    run: int
    code: int
    iterations: int | None
    given_up: list[str]
    took: int
    reached: int
    kept: int
    wall_s: float
    error: str
    resent: int = 0
    left: int = 0
    speedup: float = float("nan")

    @property
    def good(self) -> bool:
        return self.code == 0 and not self.given_up and self.kept >= self.reached


def one_run(args: argparse.Namespace, relay_kind: str, run: int, root: Path) -> RunResult:
    station_port = free_port()
    relay_port = free_port()
    out = root / f"{relay_kind}-{run:02d}"
    seed = args.seed + run
    faults = ["--drop", repr(args.drop), "--duplicate", repr(args.duplicate),
              "--reorder", repr(args.reorder), "--seed", str(seed)]
    if relay_kind == "econdor":
        cmd = [sys.executable, "-m", "econdor", "relay", "--listen",
               f"udpin:127.0.0.1:{relay_port}", "--to", f"udpout:127.0.0.1:{station_port}",
               *faults]
        if args.outage:
            cmd += ["--outage", args.outage]
    else:
        cmd = [sys.executable, __file__, "relay", "--listen", str(relay_port), "--to",
               str(station_port), *faults]
        if args.outage:
            cmd += ["--outage", args.outage]
    logs = root / f"{relay_kind}-{run:02d}-logs"
    logs.mkdir(parents=True, exist_ok=True)
    procs: list[subprocess.Popen[bytes]] = []
    vehicle_logs: list[Path] = []
    t0 = time.perf_counter()
    try:
        relay_log = (logs / "relay.log").open("wb")
        procs.append(subprocess.Popen(cmd, stderr=relay_log, cwd=REPO))
        sysids = list(range(1, args.vehicles + 1))
        for s in sysids:
            path = logs / f"vehicle{s}.log"
            vehicle_logs.append(path)
            vcmd = [sys.executable, "-m", "sim_vehicle.cli", "--sysid", str(s), "--mission",
                    str(args.mission), "--companion", "--connect",
                    f"udpout:127.0.0.1:{relay_port}", *args.vehicle_args]
            if args.speedup:
                vcmd += ["--speedup", repr(args.speedup)]
            procs.append(subprocess.Popen(vcmd, stdout=path.open("wb"),
                                          stderr=subprocess.STDOUT, cwd=REPO))
        rcmd = [sys.executable, "-m", "econdor", "run", str(args.mission), "--connect",
                f"udpin:127.0.0.1:{station_port}", "--out", str(out), "--quiet",
                "--vehicles", str(args.vehicles), *args.run_args]
        if args.speedup:
            rcmd += ["--speedup", repr(args.speedup)]
        station = subprocess.run(rcmd, capture_output=True, text=True, cwd=REPO)
        (logs / "station.log").write_text(station.stdout + station.stderr)
        code = station.returncode
    finally:
        for p in procs:
            stop(p)
    wall = time.perf_counter() - t0
    took = 0
    for path in vehicle_logs:
        m = re.search(r"samples (\d+);", path.read_text(errors="replace"))
        took += int(m[1]) if m else 0
    summary: dict = {}
    with contextlib.suppress(OSError, ValueError):
        summary = json.loads((out / "summary.json").read_text())
    given_up = [f"{x['sysid']}: {x['reason']}" for x in summary.get("lost_vehicles", [])]
    sysids = summary.get("sysids") or list(range(1, args.vehicles + 1))
    tlog = out / "telemetry.tlog"
    reached = sum(reached_station(tlog, sysids).values()) if tlog.exists() else 0
    resent = 0
    with contextlib.suppress(OSError):
        resent = (out / "log.jsonl").read_text().count("no answer and no sign of it")
    return RunResult(relay_kind, run, code, summary.get("iterations"), given_up, took,
                     reached, sum(kept(out, sysids).values()), wall,
                     summary.get("error") or "", resent,
                     len(summary.get("interrupted_flights") or []),
                     (summary.get("timings") or {}).get("achieved_speedup", float("nan")))


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["relay"]:
        p = argparse.ArgumentParser(prog="lossy_link.py relay")
        p.add_argument("--listen", type=int, required=True)
        p.add_argument("--to", type=int, required=True)
        p.add_argument("--drop", type=float, default=0.0)
        p.add_argument("--duplicate", type=float, default=0.0)
        p.add_argument("--reorder", type=float, default=0.0)
        p.add_argument("--seed", type=int, default=0)
        p.add_argument("--outage", default=None)
        a = p.parse_args(argv[1:])
        outage = tuple(float(x) for x in a.outage.split(":")) if a.outage else None
        return serve_relay(a.listen, a.to, a.drop, a.duplicate, a.reorder, a.seed,
                           outage)  # type: ignore[arg-type]
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--relay", default="econdor,independent")
    p.add_argument("--drop", type=float, default=0.2)
    p.add_argument("--duplicate", type=float, default=0.1)
    p.add_argument("--reorder", type=float, default=0.1)
    p.add_argument("--outage", default=None, metavar="START:SECONDS")
    p.add_argument("--mission", type=Path, default=REPO / "missions" / "demo.yaml")
    p.add_argument("--vehicles", type=int, default=3)
    p.add_argument("--speedup", type=float, default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--keep", type=Path, default=None, help="keep the run directories here")
    p.add_argument("--run-arg", dest="run_args", action="append", default=[],
                   help="extra argument for econdor run (repeat)")
    p.add_argument("--vehicle-arg", dest="vehicle_args", action="append", default=[],
                   help="extra argument for sim-vehicle (repeat)")
    args = p.parse_args(argv)
    args.mission = args.mission.resolve()
    kinds = [k.strip() for k in args.relay.split(",") if k.strip()]
    print(f"{args.runs} runs per relay of {args.mission.name}, {args.vehicles} vehicles, "
          f"drop {args.drop:.0%} duplicate {args.duplicate:.0%} reorder {args.reorder:.0%} "
          f"each way" + (f", outage {args.outage}" if args.outage else ""), flush=True)
    print(f"{'relay':>11} {'run':>3} {'exit':>4} {'iters':>5} {'given up':>8} {'took':>7} "
          f"{'reached':>7} {'kept':>7} {'wall s':>6} {'resent':>6} {'left':>4} {'speed':>5}"
          "  note", flush=True)
    results: list[RunResult] = []
    with tempfile.TemporaryDirectory(prefix="econdor-lossy-") as tmp:
        root = args.keep.resolve() if args.keep else Path(tmp)
        for kind in kinds:
            for run in range(args.runs):
                r = one_run(args, kind, run, root)
                results.append(r)
                note = "; ".join(r.given_up) or r.error
                print(f"{r.relay:>11} {r.run:>3} {r.code:>4} {r.iterations or '-':>5} "
                      f"{len(r.given_up):>8} {r.took:>7} {r.reached:>7} {r.kept:>7} "
                      f"{r.wall_s:>6.0f} {r.resent:>6} {r.left:>4} {r.speedup:>5.1f}  {note}",
                      flush=True)
    for kind in kinds:
        mine = [r for r in results if r.relay == kind]
        streak = best = 0
        for r in mine:
            streak = streak + 1 if r.good else 0
            best = max(best, streak)
        print(f"{kind}: {sum(r.good for r in mine)} of {len(mine)} runs good (completed, "
              f"nobody given up, every sample that reached the station kept); longest "
              f"streak {best}; samples kept {sum(r.kept for r in mine)} of "
              f"{sum(r.reached for r in mine)} that reached the station, "
              f"{sum(r.took for r in mine)} taken")
    return 0 if all(r.good for r in results) else 1


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt  # the runs' processes are stopped on the way out


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    if sys.argv[1:2] != ["relay"]:
        signal.signal(signal.SIGTERM, _interrupt)
    sys.exit(main())
