"""Telemetry logs in the ``.tlog`` format that pymavlink, MAVProxy and QGroundControl read.

A record is an 8-byte big-endian unsigned timestamp (microseconds since the Unix epoch) followed
by the raw MAVLink packet bytes.  The ground station logs every message it sends and receives.
"""

from __future__ import annotations

import contextlib
import struct
import time
from pathlib import Path
from typing import BinaryIO

from .codec import MAVLinkMessage

__all__ = ["TlogWriter", "read_tlog"]

_STAMP = struct.Struct(">Q")


class TlogWriter:
    """Append MAVLink packets to a tlog file.

    Parameters
    ----------
    path:
        The file to create (parent directories are created; an existing file is truncated
        unless ``append``).
    flush_interval_s:
        The file is flushed when at least this much wall time passed since the last flush, so a
        crash loses at most about this much telemetry.  ``0`` flushes every record.
    """

    def __init__(self, path: str | Path, *, flush_interval_s: float = 0.5,
                 append: bool = False) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.flush_interval_s = flush_interval_s
        self._file: BinaryIO | None = open(self.path, "ab" if append else "wb")  # noqa: SIM115
        self._last_flush = time.monotonic()
        self.records = 0
        self.error: OSError | None = None
        """The write that failed (a full disk...): the log stops there, the station goes on
        (it is written from the link's receive path, which must not break); the run
        reports it."""

    @property
    def closed(self) -> bool:
        return self._file is None

    def write(self, packet: MAVLinkMessage | bytes, t_unix_s: float | None = None) -> None:
        """Log one packet (a packed/decoded message, or its raw bytes) stamped ``t_unix_s``."""
        if self._file is None:
            return
        data = packet if isinstance(packet, bytes | bytearray) else packet.get_msgbuf()
        if not data:
            return
        stamp = time.time() if t_unix_s is None else t_unix_s
        try:
            self._file.write(_STAMP.pack(int(stamp * 1e6)) + bytes(data))
            self.records += 1
            now = time.monotonic()
            if now - self._last_flush >= self.flush_interval_s:
                self._file.flush()
                self._last_flush = now
        except OSError as exc:
            self._fail(exc)

    def _fail(self, exc: OSError) -> None:
        self.error = exc
        file, self._file = self._file, None
        if file is not None:
            with contextlib.suppress(OSError):  # the same failure, flushing the buffer
                file.close()

    def flush(self) -> None:
        if self._file is not None:
            try:
                self._file.flush()
            except OSError as exc:
                self._fail(exc)

    def close(self) -> None:
        if self._file is not None:
            try:
                self._file.close()
            except OSError as exc:
                self.error = exc
            self._file = None

    def __enter__(self) -> TlogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_tlog(path: str | Path) -> list[MAVLinkMessage]:
    """Every message in a tlog, parsed by pymavlink's own reader (``mavutil``).

    Each message carries its log time in ``msg._timestamp`` (Unix seconds).
    """
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path), dialect="common", robust_parsing=True)
    out: list[MAVLinkMessage] = []
    try:
        while True:
            msg = conn.recv_msg()
            if msg is None:
                break
            if msg.get_type() != "BAD_DATA":
                out.append(msg)
    finally:
        conn.close()
    return out
