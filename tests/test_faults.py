"""Fault tests over real processes: a lossy link, a signed one (README, "Fault tests").

The station (``econdor run``), the vehicles (``sim-vehicle``) and the relay (``econdor
relay``) each run as their own process, as a user would run them.
"""

from __future__ import annotations

import contextlib
import csv
import json
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

from vehicle_helpers import DEMO, VehicleProcess, free_port

from econdor import cli


class RelayProcess:
    """``econdor relay`` in its own process; ``stats`` holds its exit line."""

    def __init__(self, to_port: int, *faults: str) -> None:
        self.cmd = [sys.executable, "-m", "econdor", "relay", "--listen", "udpin:127.0.0.1:0",
                    "--to", f"udpout:127.0.0.1:{to_port}", *faults]
        self.proc: subprocess.Popen[str] | None = None
        self.port = 0
        self.stats = ""

    def __enter__(self) -> RelayProcess:
        self.proc = subprocess.Popen(self.cmd, stderr=subprocess.PIPE, text=True)
        assert self.proc.stderr is not None
        ready = self.proc.stderr.readline()
        m = re.search(r"listening on udpin:127\.0\.0\.1:(\d+)", ready)
        assert m, ready
        self.port = int(m[1])
        return self

    def __exit__(self, *exc: object) -> None:
        assert self.proc is not None
        self.proc.terminate()
        _, err = self.proc.communicate(timeout=10)
        self.stats = err.strip().splitlines()[-1] if err.strip() else ""


def vehicle_counts(procs: list[VehicleProcess]) -> dict[int, int]:
    """Each vehicle's own count of the samples it took (its exit line)."""
    out = {}
    for sysid, p in enumerate(procs, start=1):
        m = re.search(r"samples (\d+);", p.output())
        assert m, p.output()
        out[sysid] = int(m[1])
    return out


def test_demo_through_a_lossy_signed_link_keeps_every_sample(tmp_path: Path, capsys) -> None:
    """missions/demo.yaml (3 vehicles, 5 iterations) through ``econdor relay --drop 10%``
    each way, signed: the run completes and samples.csv holds, per vehicle, exactly the
    samples the vehicle says it took."""
    key = tmp_path / "key"
    key.write_text("lossy but signed\n")
    out = tmp_path / "run"
    station_port = free_port()
    with RelayProcess(station_port, "--drop", "10%", "--seed", "7") as relay, \
            contextlib.ExitStack() as stack:
        vehicles = [stack.enter_context(VehicleProcess(
            "--speedup", "100", "--signing-key", str(key), mission=DEMO, sysid=s,
            connect=f"udpout:127.0.0.1:{relay.port}")) for s in (1, 2, 3)]
        code = cli.main(["run", str(DEMO), "--connect", f"udpin:127.0.0.1:{station_port}",
                         "--out", str(out), "--quiet", "--speedup", "100",
                         "--signing-key", str(key), "--timeout", "10"])
        err = capsys.readouterr().err
        for v in vehicles:
            assert v.stop() == 0
        counts = vehicle_counts(vehicles)
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    with (out / "samples.csv").open() as f:
        per_index = Counter(int(r["vehicle"]) for r in csv.DictReader(f))
    assert {sysid: per_index[i] for i, sysid in enumerate(summary["sysids"])} == counts
    assert summary["samples_recorded"] == sum(counts.values()) == summary["samples"]
    recovery = summary["sample_recovery"]
    assert all(r["missing"] == 0 and r["vehicle_count"] == counts[int(s)]
               for s, r in recovery.items())
    assert sum(r["recovered"] for r in recovery.values()) > 0.05 * sum(counts.values())
    assert summary["iterations"] == 5 and summary["signed"] is True
    m = re.search(r"in (\d+) out \d+ dropped (\d+).*back: in (\d+) out \d+ dropped (\d+)",
                  relay.stats)
    assert m, relay.stats
    for sent, dropped in ((int(m[1]), int(m[2])), (int(m[3]), int(m[4]))):
        assert 0.08 < dropped / sent < 0.12  # 10 % each way, as asked
    # every trace item has its outcome (TRACE reports are recovered too)
    rows = json.loads((out / "iterations.json").read_text())
    assert not any(r["outcomes"].get("unreported") for r in rows)
    print(f"FAULT lossy-signed demo: {summary['samples']} samples, "
          f"{sum(r['recovered'] for r in recovery.values())} recovered, "
          f"final MAE {summary['final_mae_db']:.1f} dB, "
          f"{summary['timings']['total_wall_s']:.0f} s wall "
          f"(recovery {summary['timings']['recovery_s']:.1f} s); relay: {relay.stats}",
          file=sys.__stderr__)
