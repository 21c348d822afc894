"""pymavlink as a pure codec: messages <-> bytes, no sockets, no global dialect.

The ground station speaks MAVLink 2 of the ``common`` dialect as system 255, component 190
(DESIGN.md §4).  :class:`Codec` packs messages with our identity and a running sequence number;
:class:`Parser` turns arbitrary datagram bytes into messages and never raises: garbage, bad
CRCs and truncated packets are dropped and counted.

Build messages with the dialect module re-exported here, e.g.
``mavlink.MAVLink_heartbeat_message(...)``, or with ``Codec.mav.<name>_encode(...)``.
"""

from __future__ import annotations

import struct
from collections import Counter
from typing import TypeAlias

from pymavlink.dialects.v20 import common as mavlink

from econdor_gcs.link.signing import (
    SigningKey,
    refusal_counts,
    refusal_counts_by_source,
    refused,
    share_signing,
    unsigned_sources,
)

__all__ = ["GCS_COMPONENT_ID", "GCS_SYSTEM_ID", "Codec", "MAVLinkMessage", "Parser", "mavlink"]

GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = 190

MAVLinkMessage: TypeAlias = mavlink.MAVLink_message


class Codec:
    """Encode messages as one sender (default: the GCS, 255/190), MAVLink 2.

    Parameters
    ----------
    system_id, component_id:
        The sender identity written into every packet header.
    signing:
        Sign every packet (MAVLink 2 signing) with this key.
    """

    def __init__(self, system_id: int = GCS_SYSTEM_ID,
                 component_id: int = GCS_COMPONENT_ID, signing: SigningKey | None = None
                 ) -> None:
        self.system_id = system_id
        self.component_id = component_id
        self.mav = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self.mav.robust_parsing = True
        if signing is not None:
            signing.apply(self.mav)

    def encode(self, msg: MAVLinkMessage) -> bytes:
        """Pack ``msg`` with our identity and the next sequence number.

        After the call ``msg.get_msgbuf()`` holds the same bytes and ``msg.get_srcSystem()``
        our system id, so the message can go straight to a tlog.
        """
        data = bytes(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256
        return data


class Parser:
    """Datagram or stream bytes -> MAVLink messages, robustly.

    A call to :meth:`feed` without ``stream`` is one datagram: a packet cut off at the end of
    a datagram is discarded rather than glued to the next one (UDP keeps packets whole, so a
    fragment can only be damage). With ``stream`` (any hashable key, e.g. a TCP peer) the
    bytes continue that stream, and a packet split across reads is put back together.
    Counters:

    ``packets``
        messages decoded and returned
    ``bad_packets``
        garbage runs, bad CRCs, bad lengths, truncated packets (dropped)
    ``unknown_packets``
        well-formed packets of message ids outside the common dialect (dropped)
    ``unsigned_packets``, ``bad_signature_packets``
        with a ``signing`` key: packets without a signature, and packets whose signature
        does not match the key or replays an old timestamp (dropped, not in ``bad_packets``)
    """

    def __init__(self, signing: SigningKey | None = None) -> None:
        self.signing = signing
        self._signing_state: mavlink.MAVLinkSigning | None = None
        self._mav = self._new_mav()
        self._streams: dict[object, mavlink.MAVLink] = {}
        self.packets = 0
        self.bad_packets = 0
        self.unknown_packets = 0
        self.unsigned_packets = 0
        self.bad_signature_packets = 0
        self.unsigned_by: Counter[int] = Counter()
        """Unsigned packets dropped, by the system id they claim."""
        self.bytes = 0

    def _new_mav(self) -> mavlink.MAVLink:
        mav = mavlink.MAVLink(None)
        mav.robust_parsing = True
        if self.signing is not None:
            if self._signing_state is None:
                self.signing.apply(mav, sign_outgoing=False)
                self._signing_state = mav.signing
            else:  # a fresh parser keeps the streams' timestamps: replays stay refused
                share_signing(mav, self._signing_state)
        return mav

    @property
    def signing_state(self) -> mavlink.MAVLinkSigning | None:
        """The signing state every packet is checked against (None: not signing)."""
        return self._signing_state

    def refused_by_source(self) -> dict[int, dict[str, int]]:
        """Per system id: packets refused as ``bad_signature`` (signed with another key),
        ``replayed`` and ``unsigned`` (empty when not signing)."""
        out: dict[int, dict[str, int]] = {}
        if self._signing_state is not None:
            for (reason, sysid), n in refusal_counts_by_source(self._signing_state).items():
                out.setdefault(sysid, {})[reason] = n
        for sysid, n in self.unsigned_by.items():
            out.setdefault(sysid, {})["unsigned"] = n
        return out

    def forget(self, stream: object) -> None:
        """Drop what is buffered of ``stream`` (its connection closed)."""
        self._streams.pop(stream, None)

    def feed(self, data: bytes, stream: object = None) -> list[MAVLinkMessage]:
        """Decode every packet in one datagram, or in ``stream`` so far; never raises."""
        self.bytes += len(data)
        out: list[MAVLinkMessage] = []
        if stream is None:
            mav = self._mav
        else:
            mav = self._streams.get(stream)
            if mav is None:
                mav = self._streams[stream] = self._new_mav()
        sig = mav.signing
        before = refusal_counts(sig)
        try:
            found = mav.parse_buffer(data) or []
        except (mavlink.MAVError, struct.error, IndexError, ValueError, UnboundLocalError):
            # robust_parsing covers almost everything; whatever slips through is damage.
            self.bad_packets += 1
            if stream is None:
                self._mav = self._new_mav()
            else:
                self._streams[stream] = self._new_mav()
            return out
        wrong, unsigned = refused(sig, before)  # these came back as BAD_DATA too
        self.bad_signature_packets += wrong
        self.unsigned_packets += unsigned
        if unsigned:
            self.unsigned_by.update(unsigned_sources(data))
        refusals = wrong + unsigned
        for msg in found:
            kind = msg.get_type()
            if kind == "BAD_DATA":
                if refusals > 0:
                    refusals -= 1
                else:
                    self.bad_packets += 1
            elif kind.startswith("UNKNOWN"):
                self.unknown_packets += 1
            else:
                self.packets += 1
                out.append(msg)
        if stream is None and mav.buf_len() > 0:  # a truncated packet ends the datagram
            self.bad_packets += 1
            self._mav = self._new_mav()
        return out
