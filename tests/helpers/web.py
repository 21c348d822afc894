"""Helpers for the web page tests: a headless Debian Chromium driven by playwright, and
``econdor run --web`` / ``econdor view`` as processes whose page address is read from stdout.

Chromium is Debian's package (``/usr/bin/chromium``; ``.ci/run`` installs it when missing);
playwright only drives it (``executable_path``), it never downloads a browser. The flags
keep Chromium off the network: this machine's closed network refuses its background
connections, and the page must work offline anyway (every request that leaves the
loopback is refused and recorded).
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest

from tests.helpers.vehicles import wait_for

REPO = Path(__file__).resolve().parents[2]
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--no-first-run",
    "--disable-dev-shm-usage",  # containers often have a tiny /dev/shm
]
URL_RE = re.compile(r"^web: (http://\S+)", re.MULTILINE)


def chromium_executable() -> str | None:
    if os.path.exists("/usr/bin/chromium"):
        return "/usr/bin/chromium"
    return shutil.which("chromium")


def require_chromium() -> str:
    """The Chromium to drive; skip (outside CI) or fail (in CI) without one."""
    exe = chromium_executable()
    if exe is not None:
        return exe
    if os.environ.get("CI"):
        pytest.fail("chromium is missing in CI: .ci/run installs Debian's chromium package")
    pytest.skip("Debian's chromium package is not installed (apt-get install chromium; "
                ".ci/run does it)")


class Browser:
    """A headless Chromium with a fresh profile; :meth:`page` opens a page on a URL."""

    def __init__(self, viewport: tuple[int, int] = (1400, 900)) -> None:
        from playwright.sync_api import sync_playwright

        self.exe = require_chromium()
        self._profile = tempfile.TemporaryDirectory(prefix="econdor-chromium-")
        self._pw = sync_playwright().start()
        self.context = self._pw.chromium.launch_persistent_context(
            self._profile.name, executable_path=self.exe, args=CHROMIUM_ARGS, headless=True,
            viewport={"width": viewport[0], "height": viewport[1]})
        self.external: list[str] = []
        self.errors: list[str] = []
        self.context.route("**/*", self._route)

    def _route(self, route: Any) -> None:
        host = urlsplit(route.request.url).hostname or ""
        if host in ("127.0.0.1", "localhost", "::1") or route.request.url.startswith("data:"):
            route.continue_()
        else:
            self.external.append(route.request.url)
            route.abort()

    def page(self, url: str) -> Any:
        page = self.context.new_page()
        page.on("pageerror", lambda exc: self.errors.append(f"page error: {exc}"))
        page.on("console", lambda m: self.errors.append(f"console {m.type}: {m.text}")
                if m.type == "error" else None)
        page.goto(url)
        return page

    def close(self) -> None:
        from playwright.sync_api import Error as PlaywrightError

        with contextlib.suppress(PlaywrightError):  # the browser may already be gone
            self.context.close()
        self._pw.stop()
        self._profile.cleanup()

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class EcondorProcess:
    """``python -m econdor ARGS`` with its output in a file; :attr:`url` from ``web: URL``."""

    def __init__(self, *args: str, timeout_s: float = 60.0) -> None:
        self.log = tempfile.NamedTemporaryFile(  # noqa: SIM115 - closed in close()
            "w+b", prefix="econdor-", suffix=".log", delete=False)
        self.cmd = [sys.executable, "-m", "econdor", *args]
        self.proc = subprocess.Popen(self.cmd, stdout=self.log, stderr=subprocess.STDOUT,
                                     cwd=REPO, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:  # the line, or the process's end without it
            seen = wait_for(lambda: URL_RE.search(self.output()) or self.proc.poll() is not None,
                            timeout_s, "the 'web:' line", interval=0.05)
        except TimeoutError:
            seen = None
        if not isinstance(seen, re.Match):
            self.close()
            raise RuntimeError(f"no 'web:' line from {' '.join(self.cmd)}:\n{self.output()}")
        self.url = seen[1]

    def output(self) -> str:
        return Path(self.log.name).read_text(errors="replace")

    def wait(self, timeout_s: float) -> int:
        try:
            return self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"{' '.join(self.cmd)} still running after {timeout_s} s:\n"
                                 + self.output()) from None

    def close(self) -> None:
        """SIGTERM (the run then brings its vehicles down and stops them), wait, kill."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log.close()
        with contextlib.suppress(OSError):
            os.unlink(self.log.name)


# -- reading the page (DOM and canvas pixels) ------------------------------------------------


_VEHICLE_ROW = """tr => [tr.dataset.sysid,
    Object.fromEntries([...tr.cells].filter(td => td.className)
      .map(td => [td.className.replace('num ', ''), td.textContent]))]"""
"""A row of the vehicles table as ``[sysid, {column class: text}]`` (JavaScript)."""


def vehicle_rows(page: Any) -> dict[int, dict[str, str]]:
    """The vehicles table: sysid -> {column class: text}."""
    rows = page.eval_on_selector_all("#vehicles tbody tr", f"rows => rows.map({_VEHICLE_ROW})")
    return {int(sysid): cells for sysid, cells in rows}


def pieces_and_vehicles(page: Any) -> tuple[str, list[list[str]], dict[int, dict[str, str]]]:
    """The pieces table's title and rows and the vehicles table (as :func:`vehicle_rows`),
    read in one go: the page cannot redraw between them."""
    title, pieces, rows = page.evaluate(f"""() => [
        document.getElementById('pieces-title').textContent || '',
        [...document.querySelectorAll('#pieces tbody tr')]
            .map(tr => [...tr.cells].map(td => td.textContent)),
        [...document.querySelectorAll('#vehicles tbody tr')].map({_VEHICLE_ROW})]""")
    return title, pieces, {int(sysid): cells for sysid, cells in rows}


def positions_of(rows: dict[int, dict[str, str]]) -> dict[int, tuple[float, float]]:
    out = {}
    for sysid, cells in rows.items():
        try:
            out[sysid] = (float(cells["x"]), float(cells["y"]))
        except (KeyError, ValueError):
            continue  # no position yet ("–")
    return out


def vehicle_positions(page: Any) -> dict[int, tuple[float, float]]:
    return positions_of(vehicle_rows(page))


def estimate_iteration(page: Any) -> int | None:
    """The iteration whose estimate the map's colour layer shows."""
    text = page.get_attribute("#estimate", "data-iteration")
    return int(text) if text not in (None, "") else None


_CANVAS_SEEN = """c => {
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let h = 0x811c9dc5, n = 0;
    for (let i = 0; i < d.length; i++) { h ^= d[i]; h = Math.imul(h, 0x01000193) >>> 0; }
    for (let i = 3; i < d.length; i += 4) if (d[i] > 0) n++;
    return [c.dataset.iteration || "", h.toString(16) + ':' + c.width + 'x' + c.height,
            n / (d.length / 4)]; }"""
"""What a canvas shows, read at once: its ``data-iteration``, a hash (FNV-1a) of its pixels
and the share of them painted (not transparent)."""


def canvas_digest(page: Any, selector: str = "#estimate") -> str:
    """A hash (FNV-1a, in the page) of a canvas's pixels: what a person sees there."""
    return str(page.eval_on_selector(selector, _CANVAS_SEEN)[1])


def estimate_shown(page: Any) -> tuple[int | None, str, float]:
    """The estimate layer's iteration, :func:`canvas_digest` and
    :func:`canvas_coloured_fraction`, read in one evaluation: the page cannot draw the next
    iteration between them (two reads could pair one iteration's number with the next one's
    pixels)."""
    it, digest, painted = page.eval_on_selector("#estimate", _CANVAS_SEEN)
    return (int(it) if it else None), str(digest), float(painted)


def canvas_coloured_fraction(page: Any, selector: str = "#estimate") -> float:
    """Share of a canvas's pixels that are painted (not transparent)."""
    return float(page.eval_on_selector(selector, _CANVAS_SEEN)[2])


def confirm_control(page: Any, button: str) -> None:
    """Click a control button and confirm in the page's dialog."""
    page.click(button)
    page.wait_for_selector("#confirm[open]")
    page.click("#confirm-ok")
    page.wait_for_selector("#confirm:not([open])", state="attached")
