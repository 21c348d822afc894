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
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import EcondorError

__all__ = ["SigningKey", "load_signing_key", "signing_timestamp"]

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


def _refuse_unsigned(mav: Any, msg_id: int) -> bool:
    return False


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
