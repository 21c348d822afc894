"""The page's HTTP + WebSocket server: aiohttp on its own thread and event loop.

Why aiohttp: one well-kept package (aio-libs) gives an asyncio HTTP server, WebSockets
and static files, and runs on any event loop we start (:class:`aiohttp.web.AppRunner`), so
the page gets a thread of its own and never shares the station's MAVLink loop. Starlette +
uvicorn would need three packages (a WebSocket implementation on top) for the same.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import ipaddress
import json
import logging
import secrets
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from aiohttp import WSMsgType, web

from econdor_gcs.app.web.feed import Cursor, Feed
from econdor_gcs.app.web.messages import Message
from econdor_gcs.errors import ControlError, WebError

log = logging.getLogger(__name__)

STATIC_DIR = Path(__file__).parent / "static"
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
CSP = ("default-src 'self'; connect-src 'self'; img-src 'self' data: blob:; "
       "style-src 'self'; script-src 'self'; object-src 'none'; base-uri 'none'; "
       "frame-ancestors 'none'")
"""Nothing but this server: the page works offline and cannot be made to load anything else."""


def parse_web_address(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` -> ``(host, port)``; the host defaults to loopback.

    >>> parse_web_address("8765")
    ('127.0.0.1', 8765)
    >>> parse_web_address("0.0.0.0:80")
    ('0.0.0.0', 80)
    >>> parse_web_address("[::1]:0")
    ('::1', 0)
    """
    host, sep, port_text = text.strip().rpartition(":")
    if not sep:
        host = DEFAULT_HOST
    host = host.strip()
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    elif ":" in host:
        raise WebError(f"--web {text!r}: write an IPv6 address in brackets, e.g. [::1]:8765")
    try:
        port = int(port_text)
    except ValueError:
        raise WebError(f"--web {text!r}: expected [HOST:]PORT, e.g. 127.0.0.1:8765") from None
    if not 0 <= port <= 65535:
        raise WebError(f"--web {text!r}: port must be 0..65535")
    return host or DEFAULT_HOST, port


def is_loopback(host: str) -> bool:
    """
    >>> is_loopback("127.0.0.2"), is_loopback("localhost"), is_loopback("0.0.0.0")
    (True, True, False)
    """
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass(eq=False)
class _Page:
    """One connected page."""

    ws: web.WebSocketResponse
    may_control: bool = False
    """The socket was opened with the token: its ``control`` requests are obeyed."""
    cursor: Cursor = field(default_factory=Cursor)
    requests: asyncio.Queue[dict[str, Any]] = field(default_factory=asyncio.Queue)


class WebServer:
    """Serves one :class:`~.feed.Feed` to any number of pages.

    Parameters
    ----------
    feed:
        The live run or the replay.
    host, port:
        Where to listen (port 0: any free one; :attr:`url` tells).
    token:
        The page's secret (``?token=``): given, every request needs it. ``None``: a fresh
        random one when one is needed: on any host other than loopback (then every request
        needs it) and for ``controls``.
    controls:
        The feed takes operator requests (pause, resume, stop). They are obeyed only on a
        socket opened with the token, whatever its ``Origin``: a page of another site
        (or a sandboxed one, whose ``Origin`` is ``null``) cannot know it. On a loopback
        host, a page without the token still sees the run, without the controls.
    rate_hz:
        How often each page is sent what changed (vehicle positions, trails, log lines).

    Access: on any other host than loopback (or with a ``token`` given), every request needs
    the token. Otherwise the ``Host`` header must name a loopback address (no DNS
    rebinding). Sockets from
    another origin, ``null`` included, are refused.
    """

    def __init__(self, feed: Feed, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, *,
                 token: str | None = None, controls: bool = False,
                 rate_hz: float = 4.0) -> None:
        self.feed = feed
        self.host = host
        self.port = port
        self.loopback = is_loopback(host)
        self.controls = controls
        self.token_required = token is not None or not self.loopback
        """Every request needs the token (not only the controls)."""
        self.token = token if token is not None else (
            secrets.token_urlsafe(18) if controls or not self.loopback else None)
        self.rate_hz = rate_hz
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._runner: web.AppRunner | None = None
        self._pages: set[_Page] = set()
        self._closing = False
        self.bound_port = port

    # -- lifecycle -------------------------------------------------------------------------------
    def _run(self, loop: asyncio.AbstractEventLoop) -> None:
        asyncio.set_event_loop(loop)
        loop.run_forever()

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        query = f"?token={self.token}" if self.token else ""
        return f"http://{host}:{self.bound_port}/{query}"

    def start(self) -> str:
        """Bind and serve; returns the page's address (with its token, if any).

        Raises :class:`WebError` when the address cannot be bound."""
        loop = self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._run, args=(loop,), name="econdor-web",
                                        daemon=True)
        self._thread.start()
        try:
            asyncio.run_coroutine_threadsafe(self._start(), loop).result(15.0)
        except OSError as exc:
            self._stop_loop()
            raise WebError(f"--web {self.host}:{self.port}: cannot listen "
                           f"({exc.strerror or exc})") from None
        return self.url

    async def _start(self) -> None:
        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._websocket)
        app.router.add_static("/static/", STATIC_DIR)
        runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await runner.setup()
        site = web.TCPSite(runner, self.host, self.port)
        try:
            await site.start()
        except OSError:
            await runner.cleanup()
            raise
        self._runner = runner
        addresses = runner.addresses
        if addresses:
            self.bound_port = int(addresses[0][1])

    def stop(self, flush_s: float = 2.0) -> None:
        """Send every page what it has not seen yet (the run's end), close, stop the thread."""
        if self._thread is None or self._loop is None or not self._thread.is_alive():
            return
        fut = asyncio.run_coroutine_threadsafe(self._shutdown(flush_s), self._loop)
        try:
            fut.result(flush_s + 5.0)
        except TimeoutError:
            log.warning("web: the server did not shut down within %.0f s", flush_s + 5.0)
        self._stop_loop()

    def _stop_loop(self) -> None:
        assert self._loop is not None and self._thread is not None
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5.0)
        if not self._thread.is_alive():
            self._loop.close()

    async def _shutdown(self, flush_s: float) -> None:
        self._closing = True
        pages = list(self._pages)
        if pages:
            await asyncio.wait([asyncio.ensure_future(self._flush(p)) for p in pages],
                               timeout=flush_s)
        for p in pages:
            await p.ws.close(code=1001, message=b"run finished")
        if self._runner is not None:
            await self._runner.cleanup()

    async def _flush(self, page: _Page) -> None:
        for msg in self.feed.updates(page.cursor):
            await self._send(page, msg)

    @property
    def exposed(self) -> bool:
        """Served beyond this machine (any other host than loopback)."""
        return not self.loopback

    # -- access ----------------------------------------------------------------------------------
    def _has_token(self, request: web.Request) -> bool:
        if self.token is None:
            return False
        given = request.query.get("token", "")
        return hmac.compare_digest(given.encode(), self.token.encode())

    def _refuse(self, request: web.Request) -> str | None:
        """Why ``request`` may not have the page (``None``: it may)."""
        if self.token_required:
            if not self._has_token(request):
                return "this page needs the token printed when the server started (?token=...)"
        else:
            name = urlsplit(f"//{request.host}").hostname or ""
            if not is_loopback(name):  # DNS rebinding: a foreign name resolving to us
                return f"host {request.host!r} is not a loopback address"
        origin = request.headers.get("Origin")
        if origin is not None and urlsplit(origin).netloc != request.host:
            # "null" too: a sandboxed frame or a file:// page; our own page never sends it
            return f"cross-origin request from {origin} refused"
        return None

    async def _index(self, request: web.Request) -> web.StreamResponse:
        why = self._refuse(request)
        if why:
            return web.Response(status=403, text=why + "\n")
        return web.FileResponse(STATIC_DIR / "index.html", headers={
            "Content-Security-Policy": CSP, "Cache-Control": "no-store",
            "Referrer-Policy": "no-referrer", "X-Content-Type-Options": "nosniff"})

    # -- one page --------------------------------------------------------------------------------
    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        why = self._refuse(request)
        if why:
            return web.Response(status=403, text=why + "\n")
        ws = web.WebSocketResponse(heartbeat=20.0, max_msg_size=1 << 16)
        await ws.prepare(request)
        page = _Page(ws, may_control=self.controls and self._has_token(request))
        self._pages.add(page)
        sender = asyncio.ensure_future(self._serve(page))
        try:
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    continue
                try:
                    request_msg = json.loads(msg.data)
                except json.JSONDecodeError:
                    continue
                if isinstance(request_msg, dict):
                    page.requests.put_nowait(request_msg)
        finally:
            self._pages.discard(page)
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await sender
        return ws

    async def _send(self, page: _Page, msg: Message) -> None:
        await page.ws.send_str(json.dumps(msg, allow_nan=False, separators=(",", ":")))

    async def _serve(self, page: _Page) -> None:
        """The only writer of ``page``: updates at ``rate_hz``, answers as they come."""
        period = 1.0 / self.rate_hz
        try:
            hello = self.feed.hello()
            if hello.get("controls") and not page.may_control:
                hello = {**hello, "controls": False}  # seen without the token: no controls
            await self._send(page, hello)
            while not page.ws.closed and not self._closing:
                next_tick = time.monotonic() + period
                for msg in self.feed.updates(page.cursor):
                    await self._send(page, msg)
                while (left := next_tick - time.monotonic()) > 0 and not self._closing:
                    try:
                        req = await asyncio.wait_for(page.requests.get(), left)
                    except TimeoutError:
                        break
                    await self._answer(page, req)
        except ConnectionResetError:
            return  # the page went away mid-send
        except Exception:
            log.exception("web: serving a page failed")
            await page.ws.close(code=1011, message=b"server error (see the run's output)")

    async def _answer(self, page: _Page, req: dict[str, Any]) -> None:
        kind = req.get("type")
        if kind == "seek":
            it = req.get("iteration")
            msg = self.feed.frame(it) if isinstance(it, int) else None
            await self._send(page, msg if msg is not None else
                             {"type": "error", "text": f"no estimate stored for iteration {it}"})
        elif kind == "control":
            if not page.may_control and self.controls:
                reply: Message = {"type": "error", "text": "the controls need the token printed "
                                                          "when the run started (?token=...)"}
                log.warning("web: a %s request without the token was refused",
                            str(req.get("action"))[:20])
            else:
                try:
                    reply = self.feed.control(str(req.get("action")))
                except ControlError as exc:
                    reply = {"type": "error", "text": str(exc)}
            await self._send(page, reply)
        else:
            await self._send(page, {"type": "error", "text": f"unknown request {kind!r}"})
