"""Benchmark: does ``econdor run --web`` (server up, no browser attached) slow the run?

    python bench/web.py [--mission missions/demo.yaml] [--pairs 3] [--quick] [--page]

The same run (same mission, seed, fleet) is flown ``--pairs`` times without and with
``--web 127.0.0.1:0``, alternating which goes first, each in a fresh run directory.
Reported per variant: the median wall time, the flying and reconstruction time, and the
wall time the run directory's per-iteration files (``iterations/``, metrics, both
variants) took on the DFC thread; then the with/without ratio of each pair and of the
medians. ``--page`` adds a third variant with a headless Chromium page attached (needs
Debian's chromium and playwright; what watching costs). ``--quick`` caps runs at 2
iterations.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from fleet import quick_mission  # noqa: E402  (bench/fleet.py, beside this file)

from econdor_gcs.app.run import run_mission  # noqa: E402
from econdor_gcs.config import load_mission  # noqa: E402


def _watch(url: str, stop: threading.Event) -> None:
    """A headless Chromium page on ``url`` until ``stop`` (the --page variant)."""
    sys.path.insert(0, str(REPO / "tests"))
    from web_helpers import Browser

    with Browser() as browser:
        page = browser.page(url)
        while not stop.is_set():
            page.wait_for_timeout(200)


def one_run(mission: Any, mission_path: Path, out: Path, variant: str) -> dict[str, Any]:
    stop = threading.Event()
    watchers: list[threading.Thread] = []

    def announce(url: str) -> None:
        if variant == "page":
            t = threading.Thread(target=_watch, args=(url, stop), daemon=True)
            t.start()
            watchers.append(t)

    t0 = time.perf_counter()
    try:
        s = run_mission(mission, out, mission_path=mission_path, figures=False,
                        web=None if variant == "plain" else "127.0.0.1:0", announce=announce)
    finally:
        stop.set()
        for t in watchers:
            t.join(30)
    wall = time.perf_counter() - t0
    t = s["timings"]
    return {"wall_s": wall, "flight_s": t["flight_s"], "recon_s": t["reconstruction_s"],
            "rundir_s": t.get("rundir_s", 0.0), "iterations": s["iterations"],
            "samples": s["samples"], "mae_db": s["final_mae_db"]}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--mission", type=Path, default=REPO / "missions" / "demo.yaml")
    p.add_argument("--pairs", type=int, default=3)
    p.add_argument("--quick", action="store_true", help="2 iterations per run")
    p.add_argument("--page", action="store_true", help="also a variant with a page attached")
    args = p.parse_args(argv)
    variants = ["plain", "web"] + (["page"] if args.page else [])
    with tempfile.TemporaryDirectory(prefix="econdor-bench-web-") as tmp:
        mission_path = quick_mission(args.mission, Path(tmp)) if args.quick else args.mission
        mission = load_mission(mission_path)
        print(f"mission {mission.name}, {mission.vehicles.count} vehicles, speedup "
              f"{mission.vehicles.speedup:g}x, {args.pairs} rounds of {', '.join(variants)}")
        print(f"{'round':>5} {'variant':>7} {'wall s':>7} {'flying':>7} {'recon':>6} "
              f"{'rundir':>7} {'iters':>5} {'samples':>8} {'MAE dB':>7}")
        results: dict[str, list[dict[str, Any]]] = {v: [] for v in variants}
        for k in range(args.pairs):
            order = variants if k % 2 == 0 else variants[::-1]
            for v in order:
                r = one_run(mission, mission_path, Path(tmp) / f"{v}-{k}", v)
                results[v].append(r)
                print(f"{k:>5} {v:>7} {r['wall_s']:>7.2f} {r['flight_s']:>7.2f} "
                      f"{r['recon_s']:>6.2f} {r['rundir_s']:>7.3f} {r['iterations']:>5} "
                      f"{r['samples']:>8} {r['mae_db']:>7.1f}", flush=True)
        base = results["plain"]
        med = {v: statistics.median(r["wall_s"] for r in rs) for v, rs in results.items()}
        for v in variants[1:]:
            ratios = [w["wall_s"] / b["wall_s"] for w, b in zip(results[v], base, strict=True)]
            print(f"{v} / plain wall time: median {med[v]:.2f} / {med['plain']:.2f} s = "
                  f"{med[v] / med['plain']:.3f}; per round "
                  + ", ".join(f"{x:.3f}" for x in ratios))
        fly = {v: statistics.median(r["flight_s"] for r in rs) for v, rs in results.items()}
        for v in variants[1:]:
            print(f"{v} / plain flying time (waiting for the vehicles; the MAVLink side): "
                  f"median {fly[v]:.2f} / {fly['plain']:.2f} s = {fly[v] / fly['plain']:.3f}")
        share = [r["rundir_s"] / r["wall_s"] for rs in results.values() for r in rs]
        print(f"run directory per-iteration files on the DFC thread: "
              f"{100 * statistics.median(share):.2f} % of the wall time (median, all runs)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
