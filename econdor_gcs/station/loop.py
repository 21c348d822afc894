"""The station's event loop on a background thread, serving the GCS endpoint.

:class:`Station` runs an asyncio event loop on a thread of its own that owns the GCS
:class:`~.link.Router` (one UDP endpoint, vehicles routed by system id, every message to
``telemetry.tlog``). The synchronous world (the :class:`~.dfc.Dfc` loop in the main
thread) submits coroutines with :meth:`Station.call`; Ctrl-C / SIGTERM interrupt that wait
in the main thread and the ``finally`` blocks close everything. That loop thread alone owns
the vehicle state: other threads get their answers made there (:meth:`Station.run_sync`).
It heartbeats every :data:`GCS_HEARTBEAT_S`. With signing, the station's signing
timestamps are kept on disk
(:class:`~.signing.SigningStore`), saved every second and at close.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import threading
import time
from collections.abc import Callable, Coroutine, Sequence
from typing import Any, TypeVar

from econdor_gcs.errors import VehicleTimeout
from econdor_gcs.link.router import Router
from econdor_gcs.link.signing import SigningKey, SigningStore
from econdor_gcs.link.tlog import TlogWriter

__all__ = ["Station"]

T = TypeVar("T")
log = logging.getLogger(__name__)

GCS_HEARTBEAT_S = 0.5
"""The station's HEARTBEAT period. The vehicles' GCS failsafe acts after 5 s without one
(ArduPilot's FS_GCS_TIMEOUT): at 1 Hz and 20 % loss, five in a row are lost in 1 of 3,000
seconds, about once a run of three vehicles over a bad radio, each time flying a healthy
vehicle home; at 2 Hz, ten in a row: 1 in 10 million."""



class Station:
    """The GCS endpoint (a :class:`Router`) served by an event loop on a background thread."""

    def __init__(self, endpoint: str | Sequence[str], tlog: TlogWriter | None = None,
                 heartbeat_timeout_s: float = 20.0, signing: SigningKey | None = None) -> None:
        self.loop = asyncio.new_event_loop()
        self.router = Router(endpoint, tlog=tlog, heartbeat_timeout_s=heartbeat_timeout_s,
                             gcs_heartbeat_s=GCS_HEARTBEAT_S, signing=signing)
        self._thread = threading.Thread(target=self._run, name="econdor-gcs", daemon=True)
        self._started = False
        self.close_error: str | None = None
        """Why :meth:`close` could not close the endpoint cleanly (logged), else None."""
        self.signing_store: SigningStore | None = None
        """The station's signing timestamps on disk (replays refused across restarts)."""
        self._keeper: concurrent.futures.Future[None] | None = None
        if signing is not None:
            self.signing_store = SigningStore(signing, self.router.codec.system_id)
            self.signing_store.load(*self._signing_states())
            if self.signing_store.error:
                log.warning("%s", self.signing_store.error)

    def _signing_states(self) -> tuple[Any, Any]:
        return self.router.codec.mav.signing, self.router.parser.signing_state

    async def _keep_signing(self) -> None:
        """Save the signing timestamps every second (on the loop that moves them)."""
        assert self.signing_store is not None
        while True:
            await asyncio.sleep(1.0)
            self.signing_store.save_due(*self._signing_states())

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        self.loop.run_forever()

    def start(self) -> tuple[str, int]:
        """Start the loop and bind the endpoint; return the bound ``(host, port)``."""
        self._thread.start()
        self._started = True
        self.call(self.router.start())
        if self.signing_store is not None:
            self._keeper = asyncio.run_coroutine_threadsafe(self._keep_signing(), self.loop)
        return self.router.local_address

    def call(self, coro: Coroutine[Any, Any, T], timeout_s: float | None = None) -> T:
        """Run ``coro`` on the station's loop and wait for its result (from another thread).

        The wait is interruptible (Ctrl-C); the coroutine is then cancelled.
        """
        fut = asyncio.run_coroutine_threadsafe(coro, self.loop)
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        try:
            while True:
                try:
                    return fut.result(0.2)
                except TimeoutError:
                    if fut.done():
                        raise
                    if deadline is not None and time.monotonic() > deadline:
                        raise VehicleTimeout(f"no answer within {timeout_s:g} s") from None
        except BaseException:
            fut.cancel()
            raise

    def run_sync(self, fn: Callable[[], T], timeout_s: float = 10.0) -> T:
        """Run ``fn()`` on the station's loop thread (the one thread that owns the vehicle
        state) and return its result; on that thread itself, or when the loop no longer runs
        (the error path), just call it."""
        if not self._started or not self.loop.is_running() or \
                threading.current_thread() is self._thread:
            return fn()

        async def run() -> T:
            return fn()

        return asyncio.run_coroutine_threadsafe(run(), self.loop).result(timeout_s)

    def close(self) -> None:
        if not self._started:
            self.loop.close()
            return
        if self.signing_store is not None:
            if self._keeper is not None:
                self._keeper.cancel()
            self.run_sync(lambda: self.signing_store.save(*self._signing_states())
                          if self.signing_store else None)
            if self.signing_store.error:
                log.warning("%s", self.signing_store.error)
        try:
            asyncio.run_coroutine_threadsafe(self.router.close(), self.loop).result(5.0)
        except Exception as exc:  # noqa: BLE001 - logged and kept: closing goes on regardless
            self.close_error = f"closing the GCS endpoint failed: {exc!r}"
            log.error("%s", self.close_error)
        try:  # what an interrupted wait left on the loop ends before the loop does
            asyncio.run_coroutine_threadsafe(_end_other_tasks(CLOSE_TASKS_S), self.loop).result(
                CLOSE_TASKS_S + 1.0)
        except Exception as exc:  # noqa: BLE001 - logged: closing goes on regardless
            log.error("ending the station's tasks failed: %r", exc)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(5.0)
        if not self._thread.is_alive():
            self.loop.close()
        self._started = False


CLOSE_TASKS_S = 2.0
"""How long :meth:`Station.close` waits for the tasks it cancels to end."""


async def _end_other_tasks(timeout_s: float) -> None:
    """Cancel every task on the running loop but this one and wait for them to end: a
    coroutine whose wait was interrupted (Ctrl-C during :meth:`Station.call`) is still
    on the loop, and a loop closed under it leaves "Task was destroyed but it is
    pending!" on stderr."""
    me = asyncio.current_task()
    rest = [t for t in asyncio.all_tasks() if t is not me]
    for t in rest:
        t.cancel()
    if rest:
        await asyncio.wait(rest, timeout=timeout_s)
