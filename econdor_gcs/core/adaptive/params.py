"""The adaptive planner's settings (the mission's ``adaptive`` section) and its modes.

Each mode is a :class:`enum.StrEnum`: a mission's YAML gives it as a string, and a string
compares equal to its member, so ``model: gp`` and ``Model.GP`` are one setting.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from enum import StrEnum


class LineOrientation(StrEnum):
    """Direction of the full-width line candidates."""

    NS = "ns"
    EW = "ew"
    BOTH = "both"


class Start(StrEnum):
    """The first flight (:attr:`AdaptiveParams.start`)."""

    AUTO = "auto"
    DIAGONALS = "diagonals"
    PERIMETER = "perimeter"
    PLAN = "plan"
    SURVEY = "survey"


class Model(StrEnum):
    """The variance model (:mod:`econdor_gcs.core.uncertainty`)."""

    AUTO = "auto"
    PROXY = "proxy"
    GP = "gp"


class FirstOrder(StrEnum):
    """Threshold mode: the order of the candidates that go first."""

    CROSSINGS = "crossings"
    NEAREST = "nearest"


class OpenEntry(StrEnum):
    """Threshold mode: where a component through a sampled crossing that meets the area's
    edge is entered."""

    AUTO = "auto"
    END = "end"
    CROSSING = "crossing"


class Explore(StrEnum):
    """Threshold mode: how the planner looks for what is not found yet."""

    AUTO = "auto"
    LEGS = "legs"
    LINES = "lines"


class LineWeight(StrEnum):
    """``explore: lines``: how a cell's coverage deficit is weighted."""

    NONE = "none"
    P = "p"


MODES: dict[str, type[StrEnum]] = {
    "line_orientation": LineOrientation, "start": Start, "model": Model,
    "first_order": FirstOrder, "open_entry": OpenEntry, "explore": Explore,
    "line_weight": LineWeight,
}
"""The settings that are modes, and their enums."""


@dataclass(frozen=True)
class AdaptiveParams:
    """Settings of the adaptive planner (the mission's ``adaptive`` section).

    Parameters
    ----------
    batch_m : float
        Flight planned per vehicle and iteration (m), transit included.
    batch_growth : float
        The batch grows to this fraction of the distance flown so far, if larger.
    levels : int
        Levels of the estimate whose contour pieces are candidates (MAE mode).
    piece_m : float
        Contour pieces are cut to at most this length (m).
    min_piece_m : float
        Shorter pieces are no candidates.
    leg_m : float
        Length of the exploration legs (m).
    legs : int
        Number of most uncertain places the legs pass through (four directions each).
    line_spacing_m : float
        Spacing of the full-width line candidates (0: none).
    line_orientation : LineOrientation
        Their direction(s).
    start : Start
        The first flight: the mission's initiation pattern, the area's boundary, the
        planner's own plan from its prior (uniform uncertainty: spread-out lines), or an
        even survey of ``start_lines`` north-south lines. ``auto``: the survey (it
        measured best in both modes).
    start_lines : int
        Lines of the ``survey`` start, at the centres of equal strips (the first and last
        half a spacing inside the edges, as the best survey flies them). 0 (``auto``): 16
        when mapping the whole field; one in threshold mode (a line through the middle
        costs 0.15 km against the diagonals' 0.38, and the iso-line is then found from its
        crossings and extrema). Flown in steps (one vehicle, ``start_step_m``), that one
        line runs from the vehicle straight through the area's centre
        (:func:`~econdor_gcs.core.routes.start_line`: from the home corner, the
        diagonal), so it samples from its first metre.
    start_step_m : float
        Threshold mode: the start survey is flown in steps of this length (m; 0: in one
        piece), each an iteration of its own, and a component through a crossing that a
        step sampled is traced before the next step: a start that meets the iso-line
        early traces it at once, and when that was all there was, the rest of the
        survey is never flown. Until the survey is whole a trace may run the area's
        perimeter (the estimate's component, from a part of the line, can be far too
        short for the twice-its-length cap). The lines through uncovered ground
        (``explore: lines``) are flown in these steps too. A vehicle cannot stop at a
        crossing a step samples: what the step flies beyond it is flown again on the way
        back to the trace's start, so short steps cost iterations, not distance.
    model : Model
        Variance model (:mod:`econdor_gcs.core.uncertainty`). ``auto``: the distance
        proxy when mapping the whole field (it measured best there), the GP posterior
        in threshold mode (its variance shrinks where samples surround a place, so the
        planner knows when nothing is left to find; with the length fitted it knows
        that on smooth fields too).
    length_m : float
        Length of the ``proxy`` model, and of the ``gp`` model unless ``fit_length``.
    fit_length : bool
        The ``gp`` model's length scale is fitted to the samples (else ``length_m``).
    floor : float
        Amplitude floor ``s0``; 0 picks it from the data (``sigma_f`` of the GP).
    gradient_gain_m : float
        ``l_g``: weight of the estimate's steepness in the amplitude.
    power : float
        ``f(v) = a^p v^(p/2)``: 2 integrates the variance, 1 the standard deviation.
    plan_spacing_m : float
        Spacing of the planning cells (m).
    search_radius_m : float
        Search radius of the trace tasks (m).
    trace_overhead_m : float
        Extra flight charged to a trace candidate for the onboard search (m).
    resolve_m : float
        Threshold mode: a cell within this distance of a sample is observed.
    explore_m : float
        Threshold mode: a place farther than this from every sample may hide an iso-line
        whatever the model says (the smallest feature worth looking for, in metres).
    band_m : float
        Threshold mode: cells within this distance of a sample that reads a target level
        (within ``level_tol`` of the sampled value range) are resolved: the iso-line was
        flown on there.
    level_tol : float
        See ``band_m``.
    threshold_batch_m : float
        Threshold mode: flight planned per vehicle and iteration (m), in place of
        ``batch_m``.
    crossings_first : bool
        Threshold mode: before anything else, trace the estimate's components at a target
        level that pass through a crossing of that level already sampled (where two
        consecutive survey or transit samples straddle it) and not yet traced: the iso-line
        is known to be there.
    first_order : FirstOrder
        Threshold mode: the order of the candidates that go first. ``crossings``: every
        trace through a sampled crossing (nearest first) before any probe (nearest
        first): a known iso-line removes error for sure, a probe only may find one.
        ``nearest``: the nearest of either kind next.
    open_entry : OpenEntry
        Threshold mode: where a component through a sampled crossing that meets the
        area's edge is entered (:func:`mark_crossings`). ``auto``: at an end with a
        sampled crossing within ``OPEN_END_M`` (no flight back: the onboard tracer ends
        a trace begun at the edge at the far edge), else at the crossing nearest the end
        the tracer heads for (the shortest flight back to the entry, counted in the
        cost); ``crossing``: at the crossing nearest the estimate; ``end``: at its
        nearer end.
    probes : bool
        Threshold mode: before anything else, fly a leg across the track through every
        local extremum of the samples along a flown line that falls short of a target
        level (a maximum below it, a minimum above it): the field's extremum, and a
        closed iso-line around it, may lie off the track on that perpendicular (see
        :func:`extremum_probes`).
    probe_climb : bool
        Probe the extrema of probes too (a hill-climb); else only those of other lines.
    probes_at_end : bool
        Threshold mode: once nowhere is left where the model or the coverage floor says an
        iso-line could be, fly the probes still on offer before reporting ``done`` (the
        default); else stop there. On a smooth field, where the model sees beside the
        tracks and probes wait for the end, those last probes are about a quarter of the
        flight; they find a small closed iso-line round a hill top beside a track that
        nothing else would.
    probe_m : float
        Length of those legs (m), centred on the extremum.
    probe_prominence : float
        An extremum counts when it stands out from its surroundings along the track
        (``scipy.signal.find_peaks`` prominence) by this fraction of the sampled value
        range. The simulated sensor is noise-free; with sensor noise it must exceed the
        noise several times over.
    probe_reach : float
        Probe only the extrema a level is within this many times the rise of a round
        bump, as curved along the track as the samples there, on the probe
        (:func:`~econdor_gcs.core.candidates.probe_reach`); 0: every such extremum.
    sweeps : bool
        Threshold mode: offer north-south legs over what is still farther than
        ``explore_m`` from every sample, on the centre lines of strips ``2 explore_m``
        wide less one planning cell (:func:`~econdor_gcs.core.candidates.sweep_candidates`).
    explore : Explore
        Threshold mode: how the planner looks for what is not found yet. ``legs``: the
        greedy over exploration legs, lines, sweeps and traces, scored by the straddle and
        the coverage floor, after the probes. ``lines`` (one vehicle): after every trace
        through a sampled crossing, the line flown in steps (``start_step_m``) goes on;
        then the probes, where the model is blind beside the tracks (``probe_length_m``);
        then the straight line through the most uncovered ground per metre (north-south
        or east-west, the area's full width or half of it, every ``line_step_m``; the
        coverage floor alone scores it, weighted by ``line_weight``), flown in steps too,
        so that a crossing it samples is traced at once. Once every place is within
        ``explore_m`` of a sample, what the model still scores is planned as with
        ``legs``. ``auto``: ``lines`` where the model sees beside the tracks (a smooth
        field: the fitted length is at least ``probe_length_m``), else ``legs`` (a
        narrow feature beside a track shows only as an extremum along it). Either way
        the start line is flown in steps to its end: whether the model sees beside the
        tracks cannot be told from a GP fitted to its first few metres.
    line_step_m : float
        ``explore: lines``: spacing of the lines on offer (m).
    rays : int
        ``explore: lines``: beside those, the straight lines from the vehicle to the area's
        edge in this many directions (:func:`~econdor_gcs.core.routes.ray_lines`): no
        transit to them, so a line that samples from where a trace ended competes with one
        that must be flown to first. 0: none.
    line_weight : LineWeight
        ``explore: lines``: each cell's coverage deficit counts in full (``none``) or
        weighted by ``min(1, LINE_WEIGHT_FLOOR + LINE_WEIGHT_GAIN p)``, where ``p =
        Phi(-|mu - L| / sigma)`` is the GP's probability that the cell lies on the other
        side of the level than the estimate says (``p``): lines go first where an
        iso-line the estimate does not show is likely.
    probe_length_m : float
        ``explore: lines``: probes (``probes``) go first only while the model cannot see
        beside a track: no GP fitted, one with no amplitude yet, or a fitted length scale
        below this (m); ``explore: auto`` is ``legs`` then. With a longer length (a smooth
        field) the GP-weighted lines look beside the tracks themselves. 0: always.
    target_levels : tuple of float
        Threshold mode when not empty.
    """

    batch_m: float = 200.0
    batch_growth: float = 0.0
    levels: int = 30
    piece_m: float = 30.0
    min_piece_m: float = 4.0
    leg_m: float = 30.0
    legs: int = 40
    line_spacing_m: float = 2.0
    line_orientation: LineOrientation = LineOrientation.NS
    start: Start = Start.AUTO
    start_lines: int = 0
    start_step_m: float = 5.0
    model: Model = Model.AUTO
    length_m: float = 5.0
    fit_length: bool = True
    floor: float = 0.0
    gradient_gain_m: float = 5.0
    power: float = 2.0
    plan_spacing_m: float = 2.0
    search_radius_m: float = 3.0
    trace_overhead_m: float = 5.0
    resolve_m: float = 1.5
    explore_m: float = 10.0
    band_m: float = 3.0
    level_tol: float = 0.01
    threshold_batch_m: float = 80.0
    crossings_first: bool = True
    first_order: FirstOrder = FirstOrder.CROSSINGS
    open_entry: OpenEntry = OpenEntry.AUTO
    probes: bool = True
    probe_climb: bool = True
    probes_at_end: bool = True
    probe_m: float = 30.0
    probe_prominence: float = 1e-4
    probe_reach: float = 2.0
    sweeps: bool = True
    explore: Explore = Explore.AUTO
    line_step_m: float = 5.0
    rays: int = 32
    line_weight: LineWeight = LineWeight.P
    probe_length_m: float = 20.0
    target_levels: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        # the mission's YAML (and callers) give the modes as strings: each is checked and
        # held as its enum, naming the key when it is none of them
        for f in dataclasses.fields(self):
            mode = MODES.get(f.name)
            value = getattr(self, f.name)
            if mode is None or isinstance(value, mode):
                continue
            try:
                object.__setattr__(self, f.name, mode(value))
            except ValueError:
                raise ValueError(f"{f.name}: must be one of {', '.join(mode)}; "
                                 f"got {value!r}") from None

    @property
    def threshold(self) -> bool:
        """Threshold mode: only the iso-lines at ``target_levels`` matter."""
        return bool(self.target_levels)

    def resolved(self) -> AdaptiveParams:
        """These settings with every ``auto`` decided (the ones the planner flies by):
        ``model``: the GP in threshold mode, else the distance proxy; ``start``: the
        survey; ``start_lines``: one line in threshold mode, else 16."""
        out = self
        if out.model == Model.AUTO:
            out = dataclasses.replace(out, model=Model.GP if out.threshold else Model.PROXY)
        if out.start == Start.AUTO:
            out = dataclasses.replace(out, start=Start.SURVEY)
        if out.start_lines == 0:
            out = dataclasses.replace(out, start_lines=1 if out.threshold else 16)
        return out
