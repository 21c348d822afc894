"""econdor run against ArduCopter SITL, repeated: the spread of the final MAE.

    python bench/sitl.py --runs 10 --vehicles 3 --speedup 20 [--mission missions/demo.yaml]
    python bench/sitl.py --runs 5 --out docs/results/sitl.md     # also a stamped results file

Each run starts ``--vehicles`` SITL copters (``../shared/sitl/arducopter`` or ``$ECONDOR_SITL``)
with the mission's Lua field script, runs ``econdor run --connect tcp:...`` and prints one
line per run (final MAE, samples placed against those the scripts sent, wall time), then the
median and range. SITL's timing differs from run to run, so the missions, and the MAE, do too;
the suite's SITL test asserts one run, this measures many.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

sys.path.insert(0, str(REPO / "bench"))

from report import stamp  # noqa: E402

from econdor_gcs.config import load_mission  # noqa: E402
from econdor_gcs.payload import field_script  # noqa: E402
from tests.helpers.sitl import Sitl, lua_counts, sitl_binary, sitls  # noqa: E402


def one_run(mission_path: Path, n: int, speedup: float, work: Path,
            keep: Path | None = None) -> dict[str, float]:
    lua = field_script(load_mission(mission_path))
    vehicles = [Sitl(work / f"sitl{i}", sysid=i, speedup=speedup,
                     scripts={"econdor_field.lua": lua}) for i in range(1, n + 1)]
    out = work / "run"
    t0 = time.monotonic()
    with sitls(*vehicles):
        cmd = [sys.executable, "-m", "econdor", "run", str(mission_path), "--vehicles", str(n),
               "--speedup", f"{speedup:g}", "--out", str(out), "--quiet", "--timeout", "60"]
        for v in vehicles:
            cmd += ["--connect", f"tcp:127.0.0.1:{v.port}"]
        run = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO)
    if keep is not None and out.is_dir():  # its metrics.csv: what each iteration flew
        shutil.copytree(out, keep, ignore=shutil.ignore_patterns("*.tlog"))
    if run.returncode != 0:
        return {"error": 1.0, "wall_s": time.monotonic() - t0}
    s = json.loads((out / "summary.json").read_text())
    received, sent = lua_counts(out / "telemetry.tlog")
    return {"mae_db": s["final_mae_db"], "samples": s["samples"],
            "placed_of_sent": s["samples"] / max(1, sum(sent.values())),
            "flown_m": s["flight_distance_m"], "wall_s": time.monotonic() - t0}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--vehicles", type=int, default=3)
    p.add_argument("--speedup", type=float, default=20.0)
    p.add_argument("--mission", type=Path, default=REPO / "missions" / "demo.yaml")
    p.add_argument("--keep", type=Path, default=None,
                   help="copy each run's output (but its tlog) to KEEP/run<k>")
    p.add_argument("--out", type=Path, default=None,
                   help="also write the runs and their summary here (Markdown, stamped)")
    args = p.parse_args()
    if sitl_binary() is None:
        print("no ArduPilot SITL (../shared/sitl/arducopter or $ECONDOR_SITL)", file=sys.stderr)
        return 1
    results = []
    for k in range(args.runs):
        with tempfile.TemporaryDirectory(prefix="econdor-sitl-") as tmp:
            r = one_run(args.mission, args.vehicles, args.speedup, Path(tmp),
                        None if args.keep is None else args.keep / f"run{k}")
        results.append(r)
        print(f"run {k}: " + ", ".join(f"{key} {val:.4g}" for key, val in r.items()), flush=True)
    maes = [r["mae_db"] for r in results if "mae_db" in r]
    summary = (f"final MAE dB: median {statistics.median(maes):.1f}, min {min(maes):.1f}, "
               f"max {max(maes):.1f}, <= -40 dB in {sum(m <= -40 for m in maes)} of "
               f"{len(maes)}; failed runs: {len(results) - len(maes)}" if maes
               else f"every run failed ({len(results)})")
    print(summary)
    if args.out is not None:
        write_markdown(args.out, args, results, summary)
    return 0


def write_markdown(path: Path, args: argparse.Namespace, results: list[dict[str, float]],
                   summary: str) -> None:
    """The runs as a stamped results file."""
    mission = args.mission.resolve()
    name = mission.relative_to(REPO).as_posix() if mission.is_relative_to(REPO) else mission
    lines = ["# econdor run against ArduCopter SITL", "", *stamp(sys.argv), "",
             f"{args.vehicles} SITL copters (ArduPilot's own flight code, the Lua field "
             f"script), `{name}`, speedup {args.speedup:g}, {args.runs} runs in a row on this "
             "machine. 'placed of sent': samples on the map over those the Lua scripts sent.",
             "", "| run | final MAE dB | samples | placed of sent | flown m | wall s |",
             "|---|---|---|---|---|---|"]
    for k, r in enumerate(results):
        if "mae_db" in r:
            lines.append(f"| {k} | {r['mae_db']:.1f} | {r['samples']:.0f} | "
                         f"{r['placed_of_sent']:.3f} | {r['flown_m']:.0f} | {r['wall_s']:.0f} |")
        else:
            lines.append(f"| {k} | failed | — | — | — | {r['wall_s']:.0f} |")
    lines += ["", summary[:1].upper() + summary[1:] + ".", ""]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines), encoding="utf-8")


if __name__ == "__main__":
    sys.exit(main())
