"""MAVLink 2 message signing keys (``--signing-key FILE``), shared by station and vehicle.

A key file holding exactly 64 hexadecimal characters (surrounding whitespace ignored) is the
32-byte secret itself; anything else is a passphrase, hashed with SHA-256 as MAVProxy's
``signing setup PASSPHRASE`` does, so a vehicle set up with MAVProxy and the station agree.

The secret is handed to pymavlink's signing (``MAVLink.signing``); it is never printed,
logged, or written to a tlog or a run directory. :class:`SigningKey` keeps it out of its
``repr`` for that reason.
"""

from __future__ import annotations

import hashlib
import hmac
import re
import time
import types
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import EcondorError

__all__ = ["SigningKey", "check_signature", "load_signing_key", "refusal_counts", "refused",
           "share_signing", "signing_timestamp"]

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
        return False
    link_id = msgbuf[-13]
    tlow, thigh = mav.mav_sign_unpacker.unpack(msgbuf[-12:-6])
    timestamp = tlow + (thigh << 32)
    stream = (link_id, src_system, src_component)
    last = sig.stream_timestamps.get(stream)
    if last is not None:
        if timestamp <= last:
            return False  # a replay (or a reordered packet: MAVLink refuses those too)
    elif timestamp + 6000 * 1000 < sig.timestamp:
        return False  # a "new" stream more than a minute old
    sig.stream_timestamps[stream] = timestamp
    sig.timestamp = max(sig.timestamp, timestamp)
    return True


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
