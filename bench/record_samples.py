"""Record the sample stream of a real run for ``bench/reconstruction.py``.

Usage::

    python bench/record_samples.py inprocess missions/paper.yaml --seed 0 --out bench/data/paper-s0.npz
    python bench/record_samples.py mavlink missions/demo.yaml --out bench/data/demo-mavlink.npz
    python bench/record_samples.py inprocess missions/plume.yaml --seed 900 --noise-std 1 \
        --out bench/data/plume-noise1-s900.npz

Runs the DFC loop (in-process, or over MAVLink against simulated vehicle processes) and
writes one ``.npz`` with every sample in the order the station received it, the number of
samples each reconstruction was given (the DFC's sample stream), and the true field on the
mission grid (for MAE):

========================  ============================================================
``x_m``, ``y_m``          sample positions, local ENU metres (float64)
``value``                 sensed values (float64; float32 on the wire over MAVLink)
``phase``, ``vehicle``    sample phase (``Phase``) and vehicle index
``recon_counts``          samples given to each reconstruction, in order (prefix sizes)
``truth``                 the true field on the grid, ``[row=y, col=x]``
``region``, ``grid_shape``  ``(xmin, xmax, ymin, ymax)`` and ``(ny, nx)`` of the grid
``meta``                  JSON: mission, transport, seed, planner, commit, final MAE,
                          the sensor's noise (``noise_std``: the mission's, or
                          ``--noise-std``)
========================  ============================================================

``--max-samples`` keeps the file small: the stream is cut at the last reconstruction at or
below that many samples (and the samples up to the cut are kept).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from econdor_gcs.config import load_mission  # noqa: E402
from econdor_gcs.dfc import loop as dfc_module  # noqa: E402


def _commit() -> str:
    out = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],
                         capture_output=True, text=True, check=False)
    return out.stdout.strip() or "unknown"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("transport", choices=("inprocess", "mavlink"))
    ap.add_argument("mission", type=Path)
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--planner", default=None)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--max-samples", type=int, default=0, help="cut the stream (0: keep all)")
    ap.add_argument("--noise-std", type=float, default=None,
                    help="the sensor's noise (vehicles.noise_std; default: the mission's)")
    args = ap.parse_args(argv)
    mission = load_mission(args.mission)
    if args.noise_std is not None:
        mission = mission.with_vehicles(noise_std=args.noise_std)
    seed = mission.seed if args.seed is None else args.seed

    # Note how many samples each reconstruction gets: wrap the DFC's reconstruction step.
    counts: list[int] = []
    original = dfc_module.Dfc._reconstruct

    def recording(self: dfc_module.Dfc):
        counts.append(sum(len(log) for log in self.logs))
        return original(self)

    dfc_module.Dfc._reconstruct = recording  # type: ignore[method-assign]
    try:
        if args.transport == "inprocess":
            from econdor_lab.inprocess import InProcessExecutor

            field = mission.build_field(seed)
            executor = InProcessExecutor(mission, field, seed=seed)
            dfc = dfc_module.Dfc(mission, executor, planner=args.planner, truth=field, seed=seed)
            result = dfc.run()
            samples = result.samples
            final_mae_db = result.records[-1].mae_db
        else:
            from econdor_gcs.app.run import run_mission
            from econdor_gcs.files.rundir import read_samples

            with tempfile.TemporaryDirectory(prefix="econdor-record-") as tmp:
                summary = run_mission(mission, Path(tmp) / "run", planner=args.planner,
                                      seed=seed, mission_path=args.mission, figures=False)
                samples = read_samples(Path(tmp) / "run" / "samples.csv")
            final_mae_db = summary["final_mae_db"]
            field = mission.build_field(seed)
    finally:
        dfc_module.Dfc._reconstruct = original  # type: ignore[method-assign]

    keep = counts if args.max_samples <= 0 else [c for c in counts if c <= args.max_samples]
    if not keep:
        print(f"error: the first reconstruction already had {counts[0]} samples "
              f"(> --max-samples {args.max_samples})", file=sys.stderr)
        return 1
    n = keep[-1] if args.max_samples > 0 else len(samples)
    grid = mission.grid
    xx, yy = grid.mesh
    meta = {"mission": mission.name, "transport": args.transport, "seed": seed,
            "planner": args.planner or mission.algorithm.planner, "commit": _commit(),
            "vehicles": mission.vehicles.count, "final_mae_db": final_mae_db,
            "noise_std": mission.vehicles.noise_std,
            "all_recon_counts": counts, "total_samples": len(samples)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        args.out, x_m=samples.x_m[:n], y_m=samples.y_m[:n], value=samples.value[:n],
        phase=samples.phase[:n], vehicle=samples.vehicle[:n],
        recon_counts=np.asarray(keep, dtype=np.int64),
        truth=np.asarray(field(xx, yy), dtype=np.float64),
        region=np.asarray([grid.region.xmin, grid.region.xmax, grid.region.ymin,
                           grid.region.ymax]),
        grid_shape=np.asarray(grid.shape), meta=json.dumps(meta))
    print(f"wrote {args.out}: {n} of {len(samples)} samples, reconstructions at {keep} "
          f"(run: {counts}), final MAE {final_mae_db:.1f} dB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
