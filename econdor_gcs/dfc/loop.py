"""The data fusion center loop, independent of the transport.

The DFC flies the initiation pattern, reconstructs the field, asks the planner for a
batch of jobs, assigns them to the fleet, has an :class:`Executor` fly them, collects the
samples, re-estimates, updates the planner (kappa, delta) and repeats until the stop rule.
The in-process executor (:mod:`econdor_lab.inprocess`) calls the tracer directly; the
MAVLink executor uploads missions to vehicles. Only the transport differs.

What a run produces and reports (its records, result, progress events) and the truth-only
scores are in :mod:`.records`; they are re-exported here.

Stop rule (all configurable in the mission's ``algorithm`` section):

* ``max_iterations`` reached; an iteration that sampled too little (flew under
  ``FAIR_SHARE`` of the run's largest iteration: E-CONDOR's delta may leave one level's
  few pieces, tens of metres) does not count, at most ``max_starved_iterations`` times.
  A run of a fixed number of iterations would otherwise spend its iterations on next to
  no samples: the real flight code's contours are shorter than the onboard tracer's,
  and two of a five-iteration run's iterations starve over ArduCopter SITL;
* ``flight_budget_m`` (> 0) spent;
* after ``min_iterations``: ``gamma_n = 3 E_n / (E_n + E_{n-1} + E_{n-2})`` within
  ``1 +- stop_lambda`` (``stop_lambda`` > 0; the learning error has levelled off) and the
  span of the estimate changed by less than 1 % in the last iteration; with noisy
  samples each learning error is taken net of what the noise alone moves the estimate
  by, and the span may move by that too; only iterations that flew a fair share of a
  run's largest iteration's flight are read, the last one among them (a starved iteration's
  small learning error is little sampled, not convergence: :mod:`econdor_gcs.core.stopping`);
* ``max_idle_iterations`` + 1 iterations in a row with nothing to fly (every new level
  redundant or without a contour piece): the run has stalled. An idle iteration still
  counts — its learning error is 0, which raises kappa, exactly as in the paper's loop;
* the planner says it is done (``Batch.done`` with nothing to fly; threshold mapping
  with no place left where an iso-line could be): reason ``planner_done``;
* the ``checkpoint`` asked before each iteration says stop (``stop_reason = "stopped"``,
  e.g. an operator's stop on the web page); it may also hold the loop there (pause).

Distances are booked the same way for every planner: a row of ``metrics.csv`` (and of a
study's ``study.csv``) holds the flight and the samples behind its estimate. The flight
home after the last iteration is behind no estimate: it is in no row, nor in the
summary's ``flight_distance_m`` (the last row's), but in its ``return_m`` and
``total_flown_m``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict
from typing import Protocol

import numpy as np
from threadpoolctl import threadpool_limits

from econdor_gcs.config import Mission
from econdor_gcs.core import metrics
from econdor_gcs.core.adaptive import AdaptiveParams, adaptive_planner
from econdor_gcs.core.assignment import assign_jobs
from econdor_gcs.core.fields import Field
from econdor_gcs.core.geometry import FloatArray
from econdor_gcs.core.lag import LagCorrection, correct_lag, estimate_lag, tell_lag, told_lag
from econdor_gcs.core.planners import (
    Batch,
    ContourPlanner,
    LawnmowerPlanner,
    PlanContext,
    Planner,
    diagonal_jobs,
    survey_jobs,
    survey_turn_m,
)
from econdor_gcs.core.spline import fit_field
from econdor_gcs.core.stopping import gamma_converged, noise_floor, sampled_enough
from econdor_gcs.core.tasks import FlightReport, Phase, SampleLog, Task, TraceTask
from econdor_gcs.dfc.records import (
    FINISH,
    Checkpoint,
    DfcEvent,
    FlightRecord,
    IterationDone,
    IterationPlanned,
    IterationRecord,
    Progress,
    RunDone,
    RunResult,
    RunStarted,
    isoline_errors,
    isoline_levels,
)
from econdor_gcs.errors import MissionError, RunError

__all__ = [  # the run's records and events are re-exported: most readers import them here
    "FINISH",
    "PLANNERS",
    "SPAN_NOISE_Z",
    "Checkpoint",
    "Dfc",
    "DfcEvent",
    "Executor",
    "FlightRecord",
    "IterationDone",
    "IterationPlanned",
    "IterationRecord",
    "Progress",
    "RunDone",
    "RunResult",
    "RunStarted",
    "build_planner",
    "isoline_errors",
    "isoline_levels",
]


class Executor(Protocol):
    """Flies per-vehicle task lists and reports what happened."""

    n_vehicles: int

    def positions(self) -> list[tuple[float, float]]: ...

    def fly(self, plans: list[list[Task]], iteration: int, *, survey: bool = False
            ) -> list[FlightReport]:
        """Fly ``plans``; ``survey``: the flight is the mission's initiation survey, whose
        samples the executor reports as ``Phase.SURVEY`` (the executor decides a sample's
        phase once, where it knows it; the DFC never re-tags one)."""
        ...

    def finish(self) -> list[FlightReport]:
        """Bring every vehicle home; return what was flown doing so."""
        ...


SPAN_NOISE_Z = 2.0
"""Each extreme of the estimate may move by this many standard deviations of the noise's
change in an iteration before the span counts as changed (the learning-error rule)."""


# -- planners by name -------------------------------------------------------------------------

PlannerFactory = Callable[[Mission], Planner]


def _contour_planner(sg: bool) -> PlannerFactory:
    def build(mission: Mission) -> Planner:
        a = mission.algorithm
        return ContourPlanner(
            m0=a.m0, sg=sg, lloyd_bins=a.lloyd_bins, lloyd_iterations=a.lloyd_iterations,
            min_piece_length_m=a.min_piece_length_m, search_radius_m=a.search_radius_m,
            max_trace_length_m=a.max_trace_length_m, lloyd_variant=a.lloyd_variant)

    return build


def _adaptive_planner(mission: Mission) -> Planner:
    params = AdaptiveParams(**asdict(mission.adaptive),
                            target_levels=mission.algorithm.target_levels)
    return adaptive_planner(params, seed=mission.seed)


def _lawnmower_planner(mission: Mission) -> Planner:
    lm, v = mission.lawnmower, mission.vehicles
    try:
        return LawnmowerPlanner(mission.region, lm.spacing_m, lm.budget_m, lm.lines,
                                turn_m=survey_turn_m(v.speed_mps, v.max_accel_mps2))
    except ValueError as exc:
        raise MissionError(str(exc)) from exc


PLANNERS: dict[str, PlannerFactory] = {
    "econdor": _contour_planner(sg=True),
    "no-sg": _contour_planner(sg=False),
    "lawnmower": _lawnmower_planner,
    "adaptive": _adaptive_planner,
}
"""Every planner a mission may name (``core.planners.PLANNER_NAMES``), built from the mission."""


def build_planner(name: str, mission: Mission) -> Planner:
    """The planner called ``name``, configured from ``mission``."""
    factory = PLANNERS.get(name)
    if factory is None:
        raise MissionError(f"planner: unknown planner {name!r} (one of {', '.join(PLANNERS)})")
    return factory(mission)



class Dfc:
    """One DFC run. ``truth`` (the true field) is only used for metrics, never for planning."""

    def __init__(
        self,
        mission: Mission,
        executor: Executor,
        planner: str | None = None,
        truth: Field | None = None,
        seed: int | None = None,
        progress: Progress | None = None,
        on_samples: Callable[[SampleLog], None] | None = None,
        on_flight: Callable[[FlightRecord], None] | None = None,
        replay: Sequence[FlightRecord] = (),
        checkpoint: Checkpoint | None = None,
    ) -> None:
        self.mission = mission
        self.executor = executor
        self.planner_name = planner or mission.algorithm.planner
        self.planner: Planner = build_planner(self.planner_name, mission)
        self.truth_field = truth
        self.seed = mission.seed if seed is None else seed
        self.progress: Progress = progress or (lambda event: None)
        self.on_samples = on_samples
        """Called with the samples of each flight as the DFC takes them in (displays)."""
        self.on_flight = on_flight
        """Called with each flight the executor flew, before the DFC uses its samples (the
        run directory records them: samples, then the flight's line)."""
        self._replay = {r.iteration: r for r in replay}
        self.replayed = len(self._replay)
        self._planned_from: list[tuple[float, float]] | None = None
        self.checkpoint: Checkpoint = checkpoint or (lambda iteration: True)
        self.grid = mission.grid
        self.truth = None
        if truth is not None:
            xx, yy = self.grid.mesh
            self.truth = np.asarray(truth(xx, yy), dtype=float)
        self.logs: list[SampleLog] = []
        self.records: list[IterationRecord] = []
        self.flight_m = 0.0
        self.contour_m = 0.0
        self.sim_s = 0.0
        self.recon_s = 0.0
        self._last_recon_s = 0.0
        self.return_m = 0.0
        self.noise_std = math.nan
        """The samples' noise as the last reconstruction estimated it (field units)."""
        self._samples_before = 0
        """Samples behind the last estimate recorded (the noise floor's 'before')."""
        sensor = self.mission.vehicles.sensor
        self.lag_s = (sensor.lag_s if sensor.lag_correction == LagCorrection.DECONVOLVE
                      else 0.0 if sensor.lag_correction == LagCorrection.NONE else math.nan)
        """The sensor lag the station corrects the samples for (s): the mission's when it
        is known, the last usable estimate when it is estimated (NaN before one)."""
        self._sensed: tuple[int, SampleLog] | None = None
        """With an estimated lag: the samples corrected for it, and how many there were."""

    # -- helpers --------------------------------------------------------------------------
    def _samples(self) -> SampleLog:
        """Every sample so far as the station uses it (:meth:`_as_sensed`)."""
        raw = SampleLog.concat(self.logs)
        if self.mission.vehicles.sensor.lag_correction != LagCorrection.ESTIMATE:
            return raw
        if self._sensed is None or self._sensed[0] != len(raw):
            # the lag estimated afresh from every sample's crossovers, and every sample
            # corrected with it (an earlier flight's too: the estimate firms up with flight)
            est = estimate_lag(raw)
            if est.usable:
                self.lag_s = est.lag_s
            lag = self.lag_s if math.isfinite(self.lag_s) else 0.0
            self._sensed = (len(raw), correct_lag(raw, lag) if lag > 0.0 else raw)
        return self._sensed[1]

    def _reconstruct(self) -> FloatArray:
        s = self._samples()
        if not self.mission.algorithm.keep_diagonals and len(self.records) > 0:
            s = s[s.phase != Phase.SURVEY]
        t0 = time.perf_counter()
        # One BLAS thread: the station shares the cores with the vehicles (and a study
        # with its other runs); idle BLAS threads spin and slow every process down.
        method = self.mission.algorithm.reconstruction
        with threadpool_limits(limits=1, user_api="blas"):
            rec = fit_field(s.x_m, s.y_m, s.value, self.grid, method=method)
        self._last_recon_s = time.perf_counter() - t0
        self.recon_s += self._last_recon_s
        self.noise_std = rec.noise_std
        return rec.values

    def _account(self, reports: list[FlightReport], batch: Batch | None = None) -> None:
        """Add a flight's samples and distances to the run's totals.

        ``batch`` is the planner's batch that was flown (its survey lines count as
        productive, 'contour' distance).
        """
        for r in reports:
            self.logs.append(r.samples)
            if self.on_samples is not None:
                self.on_samples(r.samples)
        self.flight_m += sum(r.flown_m for r in reports)
        self.contour_m += sum(r.traced_m for r in reports)
        if batch is not None:
            self.contour_m += batch.survey_m
        self.sim_s += max((r.sim_s for r in reports), default=0.0)

    def _as_sensed(self, reports: list[FlightReport]) -> list[FlightReport]:
        """The flights' samples as the station uses them: corrected for the sensor's known
        lag (``vehicles.sensor.lag_s``, :mod:`econdor_gcs.core.lag`), for every planner and
        transport alike. The run directory keeps the samples as received. An estimated lag
        is corrected for on all the samples at once (:meth:`_samples`): they come through
        here as received."""
        sensor = self.mission.vehicles.sensor
        if sensor.lag_s <= 0.0 or sensor.lag_correction != LagCorrection.DECONVOLVE:
            return reports
        return [dataclasses.replace(r, samples=correct_lag(
            r.samples, sensor.lag_s, LagCorrection(sensor.lag_correction))) for r in reports]

    def _tell_lag(self, plans: list[list[Task]]) -> list[list[Task]]:
        """``plans`` with every trace task carrying the sensor lag the onboard tracer is to
        trace with (:func:`~econdor_gcs.core.lag.told_lag`): the one the station corrects
        the samples for, the last usable estimate with an estimated lag."""
        correction = self.mission.vehicles.sensor.lag_correction
        if correction == LagCorrection.ESTIMATE:
            self._samples()  # brings :attr:`lag_s` up to every sample so far
        return tell_lag(plans, told_lag(correction, self.lag_s))

    def _positions(self, iteration: int) -> list[tuple[float, float]]:
        """Where the vehicles are when ``iteration`` is planned (recorded ones on replay)."""
        rec = self._replay.get(iteration)
        pos = list(rec.positions_before_m) if rec is not None else self.executor.positions()
        self._planned_from = pos
        return pos

    def _fly(self, plans: list[list[Task]], iteration: int, survey: bool = False
             ) -> list[FlightReport]:
        """Fly ``plans`` (or replay the recorded flight of ``iteration``); the samples are
        handed to ``on_flight`` -- written to disk -- before the DFC uses them. Each trace
        task is given the sensor lag the station corrects for (:meth:`_tell_lag`).

        ``survey`` marks the mission's initiation pattern: the executor is told, and its
        samples come back ``Phase.SURVEY`` (a replayed one has them so on disk).
        """
        plans = self._tell_lag(plans)
        rec = self._replay.pop(iteration, None)
        if rec is not None:
            if rec.plans != plans:
                raise RunError(f"cannot resume: the plans of iteration {iteration} differ from "
                               "the recorded ones (was the mission or the code changed?)")
            if not self._replay and rec.executor_state is not None:
                restore = getattr(self.executor, "restore", None)
                if restore is not None:  # the executor takes over from here
                    restore(rec.executor_state)
            return self._as_sensed([dataclasses.replace(
                r, samples=dataclasses.replace(r.samples), outcomes=list(r.outcomes))
                for r in rec.reports])
        before = self._planned_from if self._planned_from is not None else \
            self.executor.positions()
        reports = self.executor.fly(plans, iteration, survey=survey)
        if self.on_flight is not None:
            state = getattr(self.executor, "state", None)
            self.on_flight(FlightRecord(iteration, [list(p) for p in plans], reports,
                                        list(before), state() if state is not None else None))
        self._planned_from = None
        return self._as_sensed(reports)

    def _context(self, iteration: int, estimate: FloatArray | None) -> PlanContext:
        budget = self.mission.algorithm.flight_budget_m
        return PlanContext(
            iteration=iteration, region=self.mission.region, n_vehicles=self.executor.n_vehicles,
            grid=self.grid, estimate=estimate, samples=self._samples(),
            positions_m=self._positions(iteration),
            budget_left_m=budget - self.flight_m if budget > 0 else math.inf,
            flown_m=self.flight_m,
            noise_std=self.noise_std if math.isfinite(self.noise_std) else 0.0)

    def _pattern(self) -> tuple[Batch, list[list[Task]]]:
        """The mission's initiation pattern (the two diagonals or a survey) and its plans."""
        m = self.mission
        n = self.executor.n_vehicles
        if m.initiation.pattern == "lawnmower":
            xs = np.arange(m.region.xmin, m.region.xmax + 1e-9, m.initiation.spacing_m)
            jobs = survey_jobs(m.region, xs)
        else:
            jobs = diagonal_jobs(m.region, n)
            if len(jobs) == n:  # one diagonal share per vehicle, in order
                return Batch(jobs, levels_planned=0), [list(j.tasks) for j in jobs]
        batch = Batch(jobs, levels_planned=0)
        return batch, assign_jobs(jobs, self._positions(0), m.algorithm.search_radius_m)

    def _subsample_initiation(self, reports: list[FlightReport]) -> None:
        k = self.mission.initiation.samples_per_diagonal
        if k <= 0:
            return
        total = 2 * k
        per = max(1, total // max(1, len(reports)))
        for r in reports:
            s = r.samples
            if len(s) > per:
                r.samples = s.take(np.unique(np.linspace(0, len(s) - 1, per).round()))

    def _record(self, it: int, batch: Batch | None, estimate: FloatArray,
                previous: FloatArray | None, reports: list[FlightReport]) -> IterationRecord:
        le = metrics.learning_error(estimate, previous) if previous is not None else math.nan
        if self.truth is not None:
            mae = metrics.mae(self.truth, estimate)
            span_t = metrics.span(self.truth)
            rec_mae_rel = mae / span_t if span_t > 0 else math.nan
            sr = metrics.span_ratio(estimate, self.truth)
            iso = isoline_errors(self.truth, estimate, self.grid,
                                 self.mission.algorithm.target_levels)
        else:
            mae, rec_mae_rel, sr, iso = math.nan, math.nan, math.nan, {}
        outcomes: dict[str, int] = {}
        for r in reports:
            for o in r.outcomes:
                outcomes[o.status] = outcomes.get(o.status, 0) + 1
        traced = {o.task.level for r in reports for o in r.outcomes
                  if isinstance(o.task, TraceTask) and o.traced_m > 0}
        floor, sd_max = (0.0, 0.0)
        if previous is not None and reports:
            s = self._samples()
            floor, sd_max = noise_floor(s.x_m, s.y_m, self._samples_before, self.grid,
                                        self.noise_std if math.isfinite(self.noise_std) else 0.0)
        self._samples_before = sum(len(s) for s in self.logs)
        rec = IterationRecord(
            iteration=it,
            levels_planned=batch.levels_planned if batch else 0,
            levels_traced=len(traced),
            kappa=batch.kappa if batch else 0,
            delta=batch.delta if batch else 0.0,
            learning_error=le,
            mae=mae,
            mae_db=metrics.to_db(mae) if not math.isnan(mae) else math.nan,
            span_ratio=sr,
            contour_distance_m=self.contour_m,
            flight_distance_m=self.flight_m,
            samples=sum(len(s) for s in self.logs),
            mae_rel=rec_mae_rel,
            sim_s=self.sim_s,
            reconstruction_s=self._last_recon_s,
            levels=[float(v) for v in batch.levels] if batch else [],
            dropped=[float(v) for v in batch.dropped] if batch else [],
            pieces=len(batch.jobs) if batch else 0,
            outcomes=outcomes,
            isoline_error_m=iso,
            forced=batch.forced if batch else 0,
            noise_std=self.noise_std,
            lag_s=self.lag_s,
            noise_floor=floor,
            span_noise=SPAN_NOISE_Z * 2.0 * sd_max,
        )
        self.records.append(rec)
        self.progress(IterationDone(rec, estimate))
        return rec

    # -- the loop -------------------------------------------------------------------------
    def run(self) -> RunResult:
        wall0 = time.perf_counter()
        a = self.mission.algorithm
        self.progress(RunStarted(self.planner_name, self.seed, self.executor.n_vehicles))
        first = self.planner.initiation(self._context(0, None))
        if first is None:  # the mission's pattern; the DFC keeps only a few of its samples
            pattern, plans = self._pattern()
            self.progress(IterationPlanned(0, pattern, plans))
            reports = self._fly(plans, 0, survey=True)
            self._subsample_initiation(reports)
            self._account(reports)
        else:
            plans = assign_jobs(first.jobs, self._positions(0), a.search_radius_m)
            self.progress(IterationPlanned(0, first, plans))
            reports = self._fly(plans, 0)
            self._account(reports, batch=first)
        estimate = self._reconstruct()
        self._record(0, first, estimate, None, reports)
        converged, reason = False, "max_iterations"
        span_prev = metrics.span(estimate)
        idle = starved = 0
        it = 0
        while it < a.max_iterations + starved:
            it += 1
            if not self.checkpoint(it):
                reason = "stopped"
                break
            if a.flight_budget_m > 0 and self.flight_m >= a.flight_budget_m:
                reason = "flight_budget"
                break
            batch = self.planner.next_batch(self._context(it, estimate))
            if batch.done and not batch.jobs:
                reason = "planner_done"
                break
            idle = 0 if batch.jobs else idle + 1
            if idle > a.max_idle_iterations:
                reason = "stalled"
                break
            plans = assign_jobs(batch.jobs, self._positions(it), a.search_radius_m,
                                first_piece_id=1000 * it)
            self.progress(IterationPlanned(it, batch, plans))
            previous = estimate
            if batch.jobs:
                reports = self._fly(plans, it)
                self._account(reports, batch=batch)
                estimate = self._reconstruct()
            else:  # nothing new: the estimate (and so E_n = 0) is unchanged
                reports = []
                self._last_recon_s = 0.0
            rec = self._record(it, batch, estimate, previous, reports)
            self.planner.observe(rec.learning_error, reports)
            span_now = metrics.span(estimate)
            if it >= a.min_iterations and self._gamma_converged(span_prev, span_now):
                converged, reason = True, "learning_error_converged"
                break
            span_prev = span_now
            if starved < a.max_starved_iterations and not sampled_enough(self._flown_m())[-1]:
                starved += 1
        home_rec = self._replay.pop(FINISH, None)
        if self._replay:
            raise RunError(f"cannot resume: {len(self._replay)} recorded flights were never "
                           "reached (was the mission or the code changed?)")
        if home_rec is not None:  # it died after coming home: only the results were missing
            home = home_rec.reports
        else:
            before = self.executor.positions()
            home = self.executor.finish()
            if self.on_flight is not None:
                self.on_flight(FlightRecord(FINISH, [], home, before))
        home = self._as_sensed(home)
        if home:  # flown, and its samples kept, but behind no estimate: no row's
            flown_before = self.flight_m
            self._account(home)
            self.return_m = self.flight_m - flown_before
        result = self._result(estimate, converged, reason, time.perf_counter() - wall0,
                              starved)
        self.progress(RunDone(result.summary()))
        return result

    def _flown_m(self) -> list[float]:
        """What each iteration after the initiation flew (m), in order."""
        return [r.flight_distance_m - p.flight_distance_m
                for p, r in zip(self.records, self.records[1:], strict=False)]

    def _gamma_converged(self, span_prev: float, span_now: float) -> bool:
        """The learning-error rule, each error net of the noise floor
        (:mod:`econdor_gcs.core.stopping`)."""
        flown = dict(zip((r.iteration for r in self.records[1:]), self._flown_m(), strict=True))
        rows = [r for r in self.records if not math.isnan(r.learning_error)]
        return gamma_converged([r.learning_error for r in rows], [r.noise_floor for r in rows],
                               self.mission.algorithm.stop_lambda, span_prev, span_now,
                               self.records[-1].span_noise,
                               flown_m=[flown.get(r.iteration, 0.0) for r in rows])

    def _result(self, estimate: FloatArray, converged: bool, reason: str, wall_s: float,
                starved_iterations: int = 0) -> RunResult:
        iso = self.records[-1].isoline_error_m if self.records else {}
        return RunResult(
            planner=self.planner_name, seed=self.seed, records=self.records,
            samples=self._samples(), grid=self.grid, estimate=estimate, truth=self.truth,
            converged=converged, stop_reason=reason, vehicles=self.executor.n_vehicles,
            sim_s=self.sim_s, wall_s=wall_s, reconstruction_s=self.recon_s,
            flight_distance_m=self.flight_m - self.return_m,
            contour_distance_m=self.contour_m,
            isoline_error_m=iso,
            return_m=self.return_m,
            starved_iterations=starved_iterations,
            mission={
                "mission": self.mission.name,
                "origin": asdict(self.mission.origin),
                "region": asdict(self.grid.region),
                "area": {"width_m": self.grid.region.width_m,
                         "height_m": self.grid.region.height_m},
            },
        )
