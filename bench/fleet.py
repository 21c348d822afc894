"""Benchmark ``econdor run`` over MAVLink with fleets of 1, 3 and 10 simulated vehicles.

    python bench/fleet.py [--mission missions/demo.yaml] [--quick] [--speedup X]
                          [--vehicles 1,3,10] [--keep DIR]

For each fleet size: wall time, sim time, achieved sim-time speedup (sim time of the flights
over their wall time) against the requested one, and where the wall time went: flying
(waiting for the vehicles), returning home, reconstruction, protocol (mission uploads, arm,
start, RTL commands), and the rest (start-up, planning, figures are off). ``--quick`` caps
the run at 2 iterations.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from econdor_gcs.app.run import run_mission  # noqa: E402
from econdor_gcs.config import load_mission  # noqa: E402
from econdor_gcs.errors import EcondorError  # noqa: E402


def quick_mission(mission_path: Path, folder: Path, iterations: int = 2) -> Path:
    """A copy of the mission in ``folder`` capped at ``iterations`` (``--quick``)."""
    raw = yaml.safe_load(mission_path.read_text(encoding="utf-8"))
    raw.setdefault("algorithm", {})["max_iterations"] = iterations
    raw["algorithm"]["min_iterations"] = 1
    path = folder / "mission.yaml"
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--mission", type=Path, default=REPO / "missions" / "demo.yaml")
    p.add_argument("--quick", action="store_true", help="2 iterations per run")
    p.add_argument("--speedup", type=float, default=None)
    p.add_argument("--vehicles", default="1,3,10")
    p.add_argument("--keep", type=Path, default=None, help="keep the run directories here")
    args = p.parse_args(argv)
    fleets = [int(v) for v in args.vehicles.split(",")]
    with tempfile.TemporaryDirectory(prefix="econdor-bench-") as tmp:
        root = args.keep or Path(tmp)
        mission_path = quick_mission(args.mission, Path(tmp)) if args.quick else args.mission
        mission = load_mission(mission_path)
        header = (f"{'vehicles':>8} {'iters':>5} {'MAE dB':>7} {'wall s':>7} {'sim s':>7} "
                  f"{'speedup':>13} {'flying':>7} {'return':>7} {'recon':>7} {'proto':>6} "
                  f"{'other':>6} {'samples':>8}")
        print(f"mission {mission.name} ({mission_path}), requested speedup "
              f"{args.speedup or mission.vehicles.speedup:g}x")
        print(header)
        for n in fleets:
            t0 = time.perf_counter()
            try:
                s = run_mission(mission, root / f"fleet-{n}", vehicles=n,
                                speedup=args.speedup, mission_path=mission_path, figures=False)
            except EcondorError as exc:
                print(f"{n:>8} failed after {time.perf_counter() - t0:.1f} s: {exc}", flush=True)
                continue
            wall = time.perf_counter() - t0
            t = s["timings"]
            other = wall - t["flight_s"] - t["return_s"] - t["reconstruction_s"] - t["protocol_s"]
            print(f"{n:>8} {s['iterations']:>5} {s['final_mae_db']:>7.1f} {wall:>7.1f} "
                  f"{t['sim_s']:>7.0f} {t['achieved_speedup']:>6.1f}/{t['requested_speedup']:<5g}x "
                  f"{t['flight_s']:>7.1f} {t['return_s']:>7.1f} {t['reconstruction_s']:>7.1f} "
                  f"{t['protocol_s']:>6.2f} {other:>6.1f} {s['samples']:>8}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
