"""Watch a run in the browser: ``econdor run --web`` (live) and ``econdor view RUN_DIR`` (replay).

One page for both. It shows the current estimate as a colour map with contour lines, the
samples' paths coloured by phase, each vehicle (position, heading, state, flight time),
the pieces planned for the iteration and which vehicle has which, per-iteration curves
(MAE when the truth is known, learning error, κ, δ, distance) and the run's log lines.
Live runs add pause / resume / stop (each with a confirmation); replays add an iteration
slider (live pages have it too: it follows the newest iteration unless moved back).

Pieces:

:mod:`.messages`
    The JSON messages the page receives, built from the run's data (arrays go as
    base64 of little-endian float32 / uint8).
:mod:`.feed`
    :class:`~.feed.LiveFeed`, the live run's side: DFC progress events, the samples the
    DFC accounted, the raw samples still in flight (for the trails), vehicle snapshots
    (``executor.status_rows()``, nothing else of the executor), the log and the operator
    control. The DFC thread only appends references under a lock; everything the page
    needs is encoded on the server's thread, at most ``rate_hz`` times a second, and only
    while a page is connected.
:mod:`.replay`
    :class:`~.replay.ReplayFeed`, the same messages from a run directory alone
    (``iterations/``, ``iterations.json``, ``samples.csv``, ``log.jsonl``, ``summary.json``).
:mod:`.server`
    :class:`~.server.WebServer`: aiohttp on its own thread and event loop (never the
    station's), one WebSocket per page, the static assets from this package.

Protocol (server -> page, JSON over one WebSocket ``/ws``): ``hello`` (mode, mission,
region, vehicles, colour map), then ``records``, ``samples``, ``trail``, ``plan``, ``frame``,
``vehicles``, ``log``, ``control`` and ``done`` as things happen. Page -> server:
``{"type": "seek", "iteration": k}`` and ``{"type": "control", "action": "pause" | "resume" |
"stop"}``; a refused action comes back as ``{"type": "error", "text": ...}``.

Access: a loopback address serves anyone on this machine (the ``Host`` header must name the
loopback address, so another web site cannot reach the page through DNS rebinding; a
WebSocket from another origin is refused). Any other address needs the token printed at
start (``?token=...`` in the page's address).
"""
