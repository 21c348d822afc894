"""Live terminal display of an ``econdor run`` (rich, on stderr, a few refreshes a second)."""

from __future__ import annotations

import math
import time
from typing import Any

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from econdor_gcs.dfc.loop import DfcEvent, IterationDone, IterationPlanned


class LiveDisplay:
    """Iteration, levels, kappa, delta, MAE so far, and one row per vehicle.

    ``progress`` is the :class:`~econdor_gcs.dfc.loop.Dfc` progress callback; vehicle rows come
    from ``executor.status_rows()``.
    """

    def __init__(self, executor: Any, planner: str = "", mission: str = "",
                 refresh_per_second: float = 4.0) -> None:
        self.executor = executor
        self.planner = planner
        self.mission = mission
        self.state: dict[str, Any] = {"iteration": 0, "levels": [], "kappa": None,
                                      "delta": None, "mae_db": [], "pieces": 0}
        self.t0 = time.monotonic()
        self.console = Console(stderr=True)
        self._live = Live(get_renderable=self._render, console=self.console,
                          refresh_per_second=refresh_per_second, transient=False)

    def start(self) -> None:
        self._live.start()

    def stop(self) -> None:
        self._live.stop()

    def progress(self, event: DfcEvent) -> None:
        s = self.state
        if isinstance(event, IterationPlanned):
            b = event.batch
            s.update(iteration=event.iteration, levels=[float(v) for v in b.levels],
                     kappa=b.kappa, delta=b.delta, pieces=len(b.jobs))
        elif isinstance(event, IterationDone):
            s["mae_db"].append(event.record.mae_db)

    def _render(self) -> Group:
        s = self.state
        levels = ", ".join(f"{v:.1f}" for v in s["levels"][:8])
        if len(s["levels"]) > 8:
            levels += ", ..."
        maes = [f"{m:.1f}" for m in s["mae_db"] if m is not None and not math.isnan(m)]
        kappa = "-" if s["kappa"] is None else str(s["kappa"])
        delta = "-" if s["delta"] is None else f"{s['delta']:.2f}"
        head = Text.assemble(
            ("econdor run ", "bold"), f"{self.mission} ({self.planner})  ",
            ("iteration ", "bold"), str(s["iteration"]), "  ",
            ("κ ", "bold"), kappa, "  ", ("δ ", "bold"), delta, "  ",
            ("pieces ", "bold"), str(s["pieces"]), "  ",
            (f"{time.monotonic() - self.t0:.0f} s", "dim"))
        lv = Text.assemble(("levels ", "bold"), levels or "-")
        mae = Text.assemble(("MAE dB ", "bold"), " → ".join(maes[-6:]) or "-")
        table = Table(box=None, pad_edge=False, header_style="bold")
        for col in ("vehicle", "armed", "item", "phase", "flown m", "samples", "state",
                    "message"):
            table.add_column(col, justify="right" if col in ("flown m", "samples") else "left")
        for r in self.executor.status_rows():
            state = "[red]LOST[/]" if r.lost else r.status
            table.add_row(str(r.sysid), "yes" if r.armed else "no", f"{r.item}/{r.items}",
                          r.phase.name.lower(), f"{r.flown_m:.0f}", str(r.samples), state,
                          r.message[:40])
        return Group(head, lv, mae, table)
