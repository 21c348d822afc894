"""Fleet assignment: split jobs over vehicles so the fleet finishes soon and transit is short.

A greedy longest-processing-time heuristic with transit: jobs in decreasing length go to
the vehicle whose finish time (current load + transit to the job + job length) is
smallest; each vehicle's jobs are then ordered by nearest neighbour from its position,
and contour pieces are entered at their point nearest to where the vehicle comes from.

A planner that routes its own jobs (every job names its ``vehicle``, as the adaptive
planner's do) keeps its routing: each vehicle flies its jobs in the batch's order, as
planned; only the trace tasks' piece ids are numbered here.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from .planners import Job
from .tasks import Task, TraceTask


class _NearestPoints:
    """Nearest point of every contour piece of ``jobs`` to a query point, in one pass.

    The same point :meth:`~econdor_gcs.core.contours.ContourPiece.nearest_point` picks (the
    first point at the smallest ``hypot`` distance); jobs without a piece keep their start.
    """

    def __init__(self, jobs: Sequence[Job]) -> None:
        self.jobs = jobs
        pieces = [j.piece.points_m for j in jobs if j.piece is not None]
        self.has_piece = [j.piece is not None for j in jobs]
        self.points = np.concatenate(pieces) if pieces else np.zeros((0, 2))
        lengths = np.array([len(p) for p in pieces], dtype=np.intp)
        self.starts = np.r_[0, np.cumsum(lengths)[:-1]].astype(np.intp) if pieces else lengths

    def starts_from(self, x_m: float, y_m: float) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        if len(self.points):
            d = np.hypot(self.points[:, 0] - x_m, self.points[:, 1] - y_m)
            seg_min = np.minimum.reduceat(d, self.starts)
            at_min = np.flatnonzero(d == np.repeat(seg_min, np.diff(np.r_[self.starts, len(d)])))
            first = at_min[np.searchsorted(at_min, self.starts)]
            nearest = self.points[first].tolist()
        k = 0
        for job, has in zip(self.jobs, self.has_piece, strict=True):
            if has:
                out.append((nearest[k][0], nearest[k][1]))
                k += 1
            else:
                out.append(job.start_m)
        return out


def assign_jobs(
    jobs: Sequence[Job],
    positions_m: Sequence[tuple[float, float]],
    search_radius_m: float = 10.0,
    first_piece_id: int = 0,
) -> list[list[Task]]:
    """Return one task list per vehicle (same order as ``positions_m``)."""
    n = len(positions_m)
    if jobs and all(j.vehicle is not None and 0 <= j.vehicle < n for j in jobs):
        return _routed(jobs, n, first_piece_id)
    loads = [0.0] * n
    ends = list(positions_m)
    buckets: list[list[Job]] = [[] for _ in range(n)]
    for job in sorted(jobs, key=lambda j: -j.length_m):
        costs = [loads[v] + math.dist(ends[v], job.start_m) + job.length_m for v in range(n)]
        v = min(range(n), key=costs.__getitem__)
        loads[v] = costs[v]
        ends[v] = job.end_m
        buckets[v].append(job)
    plans: list[list[Task]] = []
    piece_id = first_piece_id
    for v in range(n):
        pos = positions_m[v]
        nearest = _NearestPoints(buckets[v])
        todo = list(range(len(buckets[v])))
        tasks: list[Task] = []
        while todo:
            # where each job would start from here (a piece: its point nearest to us)
            starts = nearest.starts_from(*pos)
            k = min(range(len(todo)), key=lambda i: math.dist(pos, starts[todo[i]]))
            job = buckets[v][todo.pop(k)]
            if job.piece is not None:
                job.retarget(*pos, search_radius_m, job.tasks[0].max_length_m, piece_id)  # type: ignore[union-attr]
                piece_id += 1
            tasks.extend(job.tasks)
            pos = job.end_m
        plans.append(tasks)
    return plans


def _routed(jobs: Sequence[Job], n: int, first_piece_id: int) -> list[list[Task]]:
    """The planner's own routing: jobs per vehicle in batch order, piece ids numbered."""
    plans: list[list[Task]] = [[] for _ in range(n)]
    piece_id = first_piece_id
    for job in jobs:
        assert job.vehicle is not None
        for task in job.tasks:
            if isinstance(task, TraceTask):
                task = dataclasses.replace(task, piece_id=piece_id)
                piece_id += 1
            plans[job.vehicle].append(task)
    return plans
