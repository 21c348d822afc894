"""MAVLink 2 message signing keys (``--signing-key FILE``), shared by station and vehicle.

A key file holding exactly 64 hexadecimal characters (surrounding whitespace ignored) is the
32-byte secret itself; anything else is a passphrase, hashed with SHA-256 as MAVProxy's
``signing setup PASSPHRASE`` does, so a vehicle set up with MAVProxy and the station agree.

The secret is handed to pymavlink's signing (``MAVLink.signing``); it is never printed,
logged, or written to a tlog or a run directory. :class:`SigningKey` keeps it out of its
``repr`` for that reason. A key file that anybody but its owner may read or write is
refused (OpenSSH's rule for private keys): one others can read signs for them, one they
can write becomes theirs, and a warning scrolls by on a run that starts a fleet.

Timestamps (MAVLink's message-signing guide, "Timestamp Handling"): the timestamp a system
signs with, and the last one accepted from each stream (link id, system, component), are
kept on disk per key and per system (:class:`SigningStore`, under :func:`state_dir`), saved
every second and at exit. A restarted vehicle or station starts from them: a packet
captured before the restart and replayed after it is refused as old, not taken as the
first of a new stream (the guide's one-minute window for new streams would let a 54 s old
ARM through). A crash loses at most the last second's streams.

:func:`check_signature` also counts what it refuses per sending system
(:func:`refusal_counts_by_source`), so a vehicle signing with another key is named as such.
"""

from __future__ import annotations

import contextlib
import hashlib
import hmac
import json
import os
import re
import time
import types
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from econdor_gcs.errors import EcondorError

__all__ = ["STATE_DIR_ENV", "SigningKey", "SigningStore", "check_signature",
           "load_signing_key", "refusal_counts", "refusal_counts_by_source", "refused",
           "share_signing", "signing_timestamp", "state_dir", "unsigned_sources"]

STATE_DIR_ENV = "ECONDOR_STATE_DIR"
"""Where the signing timestamps are kept (default ``$XDG_STATE_HOME/econdor``, or
``~/.local/state/econdor``)."""
SAVE_EVERY_S = 1.0
"""The timestamps go to disk at least this often (the guide asks for once a minute)."""

_HEX64 = re.compile(r"[0-9a-fA-F]{64}")
_EPOCH_2015 = 1420070400  # 1 January 2015 GMT, the origin of MAVLink signing timestamps


def signing_timestamp(now_unix_s: float | None = None) -> int:
    """MAVLink signing time: units of 10 microseconds since 1 January 2015 GMT.

    >>> signing_timestamp(1420070401.0)
    100000
    """
    now = time.time() if now_unix_s is None else now_unix_s
    return int((now - _EPOCH_2015) * 100_000)


@dataclass(frozen=True)
class SigningKey:
    """A 32-byte MAVLink signing secret and the link id we sign with.

    >>> SigningKey.from_text("00" * 32)
    SigningKey(<secret>, link_id=0)
    """

    secret: bytes = field(repr=False)
    link_id: int = 0

    def __post_init__(self) -> None:
        if len(self.secret) != 32:
            raise ValueError("a MAVLink signing secret has 32 bytes")
        if not 0 <= self.link_id <= 255:
            raise ValueError(f"link_id must be within 0..255, got {self.link_id}")

    def __repr__(self) -> str:
        return f"SigningKey(<secret>, link_id={self.link_id})"

    @property
    def key_id(self) -> str:
        """A name for the key that does not give it away (it names the timestamp files).

        >>> len(SigningKey(bytes(32)).key_id)
        16
        """
        return hashlib.sha256(b"econdor signing key id\0" + self.secret).hexdigest()[:16]

    @classmethod
    def from_text(cls, text: str, link_id: int = 0) -> SigningKey:
        """64 hex characters -> that secret; any other text -> SHA-256 of the passphrase.

        >>> import hashlib
        >>> SigningKey.from_text("correct horse").secret == hashlib.sha256(
        ...     b"correct horse").digest()
        True
        """
        stripped = text.strip()
        if not stripped:
            raise ValueError("an empty signing key")
        if _HEX64.fullmatch(stripped):
            return cls(bytes.fromhex(stripped), link_id)
        return cls(hashlib.sha256(stripped.encode("utf-8")).digest(), link_id)

    def apply(self, mav: Any, *, sign_outgoing: bool = True) -> None:
        """Switch on signing of a pymavlink ``MAVLink`` object: outgoing messages signed
        with a timestamp from now on, incoming ones checked; unsigned and wrongly signed
        ones are refused (they count in ``mav.signing.reject_count`` /
        ``badsig_count`` and decode as bad data)."""
        mav.signing.secret_key = self.secret
        mav.signing.link_id = self.link_id
        mav.signing.sign_outgoing = sign_outgoing
        mav.signing.timestamp = max(mav.signing.timestamp, signing_timestamp())
        mav.signing.allow_unsigned_callback = _refuse_unsigned
        share_signing(mav, mav.signing)


def _refuse_unsigned(mav: Any, msg_id: int) -> bool:
    return False


def share_signing(mav: Any, state: Any) -> None:
    """Check ``mav``'s incoming signatures against ``state`` (a ``MAVLinkSigning`` several
    parsers may share), with :func:`check_signature`."""
    mav.signing = state
    mav.check_signature = types.MethodType(check_signature, mav)


def check_signature(mav: Any, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
    """pymavlink's ``MAVLink.check_signature`` in the order the MAVLink spec gives.

    pymavlink (2.4.x) records a stream's timestamp *before* it compares the signature, so a
    forged packet with a future timestamp makes every genuine packet after it "old": one
    unsigned-key packet would cut a signed link. Here the signature is checked first (in
    constant time); only a genuine packet moves the stream's timestamp on.
    """
    sig = mav.signing
    digest = hashlib.sha256(sig.secret_key + bytes(msgbuf[:-6])).digest()[:6]
    if not hmac.compare_digest(digest, bytes(msgbuf[-6:])):
        _refused_by(sig)[("bad_signature", src_system)] += 1
        return False
    link_id = msgbuf[-13]
    tlow, thigh = mav.mav_sign_unpacker.unpack(msgbuf[-12:-6])
    timestamp = tlow + (thigh << 32)
    stream = (link_id, src_system, src_component)
    last = sig.stream_timestamps.get(stream)
    if last is not None:
        if timestamp <= last:
            # a replay (or a reordered packet: MAVLink refuses those too)
            _refused_by(sig)[("replayed", src_system)] += 1
            return False
    elif timestamp + 6000 * 1000 < sig.timestamp:
        _refused_by(sig)[("replayed", src_system)] += 1
        return False  # a "new" stream more than a minute old
    sig.stream_timestamps[stream] = timestamp
    sig.timestamp = max(sig.timestamp, timestamp)
    return True


def _refused_by(state: Any) -> Counter[tuple[str, int]]:
    counts: Counter[tuple[str, int]] | None = getattr(state, "econdor_refused_by", None)
    if counts is None:
        counts = state.econdor_refused_by = Counter()
    return counts


def refusal_counts_by_source(state: Any) -> Counter[tuple[str, int]]:
    """``(reason, system id) -> packets`` refused by :func:`check_signature` with this
    ``MAVLinkSigning`` state: ``bad_signature`` (signed with another key), ``replayed``
    (a timestamp not newer than its stream's). Unsigned packets are counted by the
    parsers (:func:`unsigned_sources`)."""
    return _refused_by(state)


def unsigned_sources(data: bytes) -> list[int]:
    """System ids of the packets in ``data`` (one datagram) that carry no signature: MAVLink
    1 packets, and MAVLink 2 packets without the signed flag.

    >>> unsigned_sources(bytes([0xFE, 0, 0, 7, 1, 0, 0, 0]))
    [7]
    """
    out, i = [], 0
    while i < len(data):
        if data[i] == 0xFD and i + 10 <= len(data):
            length, flags, sysid = data[i + 1], data[i + 2], data[i + 5]
            signed = flags & 0x01
            if not signed:
                out.append(sysid)
            i += 12 + length + (13 if signed else 0)
        elif data[i] == 0xFE and i + 6 <= len(data):
            out.append(data[i + 3])
            i += 8 + data[i + 1]
        else:
            i += 1
    return out


def refusal_counts(state: Any) -> tuple[int, int]:
    """pymavlink's counters of a ``MAVLinkSigning`` state, to diff with :func:`refused`."""
    return state.badsig_count, state.reject_count


def refused(state: Any, before: tuple[int, int]) -> tuple[int, int]:
    """(wrongly signed, unsigned) packets refused since ``before = refusal_counts(state)``.

    pymavlink decodes a refused packet as bad data after counting it: a wrong signature (or
    a replayed timestamp) in ``badsig_count`` *and* ``reject_count``, a missing one in
    ``reject_count`` only.
    """
    wrong = state.badsig_count - before[0]
    return wrong, state.reject_count - before[1] - wrong


def load_signing_key(path: str | Path, link_id: int = 0) -> SigningKey:
    """The key in ``path`` (see the module docstring); one clear error if unusable.

    The error names the file, never its content.
    """
    p = Path(path)
    try:
        mode = p.stat().st_mode
    except OSError:
        mode = 0  # read_text names the problem
    if os.name == "posix" and mode & 0o066:
        raise EcondorError(f"{p}: the signing key file may be read or written by others "
                           f"(mode {mode & 0o777:04o}); make it yours alone: chmod 600 {p}")
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise EcondorError(f"{p}: no such signing key file") from None
    except UnicodeDecodeError:
        raise EcondorError(f"{p}: the signing key file is not UTF-8 text") from None
    except OSError as exc:
        raise EcondorError(f"{p}: cannot read the signing key ({exc.strerror or exc})") from None
    try:
        return SigningKey.from_text(text, link_id)
    except ValueError as exc:
        raise EcondorError(f"{p}: {exc}") from None


# --------------------------------------------------------------------------------------------
# timestamps on disk


def state_dir() -> Path:
    """Where econdor keeps state between runs: ``$ECONDOR_STATE_DIR``, else
    ``$XDG_STATE_HOME/econdor``, else ``~/.local/state/econdor``."""
    env = os.environ.get(STATE_DIR_ENV)
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_STATE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".local" / "state") / "econdor"


class SigningStore:
    """The signing timestamps of one system (``sysid``) with one key, on disk.

    :meth:`load` puts them into pymavlink signing states (``sending``: the one we sign
    with; ``receiving``: the one that checks what arrives, shared by every parser), the
    sending timestamp from the later of the clock and the stored one; :meth:`save` (every
    :data:`SAVE_EVERY_S` through :meth:`save_due`, and at exit) writes them back,
    atomically, readable by the owner alone. A store that cannot be read or written is
    reported once in :attr:`error` and signing goes on without it (replays after a
    restart are then only refused as the guide's one-minute rule refuses them).
    """

    def __init__(self, key: SigningKey, sysid: int, folder: Path | None = None) -> None:
        self.path = (folder or state_dir()) / f"signing-{key.key_id}-{sysid}.json"
        self.error: str | None = None
        self._saved_at = 0.0

    def load(self, sending: Any, receiving: Any) -> None:
        try:
            doc = json.loads(self.path.read_text(encoding="utf-8"))
            timestamp = int(doc["timestamp"])
            streams = {(int(a), int(b), int(c)): int(t) for a, b, c, t in doc["streams"]}
        except FileNotFoundError:
            return
        except (OSError, ValueError, KeyError, TypeError) as exc:
            self.error = f"{self.path}: cannot read the signing timestamps ({exc})"
            return
        for state in (sending, receiving):
            state.timestamp = max(state.timestamp, timestamp, signing_timestamp())
        for stream, t in streams.items():
            receiving.stream_timestamps[stream] = max(t, receiving.stream_timestamps.get(
                stream, 0))

    def save(self, sending: Any, receiving: Any) -> None:
        doc = {"timestamp": max(sending.timestamp, receiving.timestamp),
               "streams": [[*k, t] for k, t in sorted(receiving.stream_timestamps.items())]}
        tmp = self.path.with_name(self.path.name + ".tmp")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(json.dumps(doc))
            os.replace(tmp, self.path)
        except OSError as exc:
            if self.error is None:
                self.error = f"{self.path}: cannot save the signing timestamps " \
                             f"({exc.strerror or exc})"
            with contextlib.suppress(OSError):
                tmp.unlink()
        self._saved_at = time.monotonic()

    def save_due(self, sending: Any, receiving: Any) -> None:
        if time.monotonic() - self._saved_at >= SAVE_EVERY_S:
            self.save(sending, receiving)
