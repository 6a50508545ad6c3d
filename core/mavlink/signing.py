"""MAVLink 2 message signing: the key, signing what we send, and checking what comes in.

The key is a passphrase hashed with SHA-256, as MAVProxy's `signing setup PASSPHRASE`
makes it (`passphrase_to_key` in its signing module): the same passphrase gives the same
32-byte key, so a vehicle set up with MAVProxy talks to the station (and the twin) with
the same words. The key file holds that
passphrase as UTF-8 text (surrounding whitespace, such as the newline `echo` adds, is not
part of it); it must be a regular file that only its owner can read or write, as ssh
insists for private keys. MAVProxy's `signing setup` takes the passphrase as one
command argument, so it hashes only the first word of several: a passphrase of several
words gives MAVProxy another key (`mavproxy_reads_differently` says so at start).

Outgoing packets are signed by pymavlink itself (`enable_signing` sets up a `MAVLink`'s
`signing`). Incoming packets are checked here, not by pymavlink's `decode`: pymavlink
records a stream's timestamp before it compares the signature, so one forged packet with
a far-future timestamp would make every genuine packet after it look replayed. This
check follows the MAVLink C library (`mavlink_signature_check`): signature first, then
the timestamp rules of the MAVLink guide:

- a known stream (link id, system id, component id) must move its timestamp forward;
- a new stream is accepted unless its timestamp is more than a minute behind ours;
- an accepted timestamp ahead of ours moves ours forward (what we send next is newer).

Unsigned packets (every MAVLink 1 packet among them) are refused, except RADIO_STATUS
and RADIO, which SiK/3DR radios inject into the link without a key (MAVProxy, ArduPilot
and the MAVLink guide all let these two through).
"""

from __future__ import annotations

import hashlib
import hmac
import os
import stat
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from fpv_station.core.mavlink.framing import MAGIC_V1, message_id

SIGNATURE_LEN = 13  # link id (1) + timestamp (6) + signature (6)
_IFLAG_SIGNED = 0x01
_EPOCH_2015 = 1420070400  # signing timestamps count 10 us units from 2015-01-01 UTC
_NEW_STREAM_SLACK = 6000 * 1000  # one minute in 10 us units
# Unsigned messages a radio adds to the link: RADIO_STATUS (109) and RADIO (166).
UNSIGNED_ALLOWED = frozenset({109, 166})

Verdict = Literal["signed", "unsigned_allowed", "unsigned", "bad_signature", "replayed"]


class SigningKeyError(ValueError):
    """A key file that cannot be used; the message says why and what to do."""


def key_from_passphrase(passphrase: str) -> bytes:
    """The 32-byte signing key of a passphrase (MAVProxy's `passphrase_to_key`)."""
    return hashlib.sha256(passphrase.encode("utf-8")).digest()


def mavproxy_reads_differently(passphrase: str) -> str | None:
    """Why MAVProxy would not share this passphrase's key, or None: MAVProxy's
    `signing setup PASSPHRASE` splits its command line on spaces and hashes only the
    first word, so a vehicle or a MAVProxy set up with several words has another key
    than ours, and each silently refuses the other's signed packets."""
    words = passphrase.split()
    if len(words) < 2:
        return None
    return (
        f"the signing passphrase has {len(words)} words; MAVProxy's 'signing setup' "
        "hashes only the first one, so a vehicle or MAVProxy set up with it there has "
        "another key and refuses the station's signed packets (and the station theirs). "
        "Use a passphrase of one word (no spaces)."
    )


def load_key_file(path: Path | str) -> bytes:
    """The signing key from a passphrase file; refuses a file others may read or change."""
    return key_from_passphrase(read_passphrase(path))


def read_passphrase(path: Path | str) -> str:
    """The passphrase in a key file (surrounding whitespace stripped), checked as
    `load_key_file` says."""
    path = Path(path).expanduser()
    try:
        st = path.stat()
    except FileNotFoundError:
        raise SigningKeyError(f"Signing key file '{path}' does not exist.") from None
    except OSError as exc:
        raise SigningKeyError(f"Signing key file '{path}' cannot be read: {exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise SigningKeyError(f"Signing key file '{path}' is not a regular file.")
    if st.st_mode & 0o077:
        raise SigningKeyError(
            f"Signing key file '{path}' is open to other users (mode "
            f"{stat.S_IMODE(st.st_mode):04o}): anyone who reads it can fly the vehicle. "
            f"Run: chmod 600 '{path}'"
        )
    try:
        passphrase = path.read_bytes().decode("utf-8").strip()
    except UnicodeDecodeError:
        raise SigningKeyError(
            f"Signing key file '{path}' is not text: it holds a passphrase (UTF-8), "
            "the one given to MAVProxy's 'signing setup' or Mission Planner."
        ) from None
    except OSError as exc:
        raise SigningKeyError(f"Signing key file '{path}' cannot be read: {exc}") from None
    if not passphrase:
        raise SigningKeyError(f"Signing key file '{path}' is empty: write a passphrase in it.")
    return passphrase


def write_key_file(path: Path | str, passphrase: str) -> Path:
    """Create a passphrase file only its owner can read (tests, first set-up)."""
    path = Path(path)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(passphrase + "\n")
    os.chmod(path, 0o600)  # O_CREAT's mode does not apply to a file that existed
    return path


def signing_timestamp(t_unix: float | None = None) -> int:
    """Now (or `t_unix`) as a signing timestamp: 10 us units since 2015-01-01 UTC."""
    t = time.time() if t_unix is None else t_unix
    return int(max(t - _EPOCH_2015, 0.0) * 100_000)


@dataclass(slots=True)
class SigningCounts:
    signed: int = 0  # accepted with a good signature
    unsigned_allowed: int = 0  # unsigned radio messages let through
    unsigned: int = 0  # refused: no signature (MAVLink 1 included)
    bad_signature: int = 0  # refused: wrong key or altered bytes
    replayed: int = 0  # refused: good signature, timestamp not newer (a replay)

    @property
    def refused(self) -> int:
        return self.unsigned + self.bad_signature + self.replayed


class SignatureCheck:
    """Checks incoming packets against the key of a pymavlink `MAVLinkSigning` (any
    dialect's), whose timestamp it moves forward as the protocol asks. One thread."""

    def __init__(self, signing: Any) -> None:
        if signing.secret_key is None:
            raise ValueError("SignatureCheck needs a MAVLinkSigning with a key")
        self._signing = signing
        self._key = bytes(signing.secret_key)
        # Last timestamp per stream. Only packets with a good signature add a stream, so
        # only holders of the key can grow this table.
        self._streams: dict[tuple[int, int, int], int] = {}
        self.counts = SigningCounts()

    def check(self, packet: bytes | bytearray, allow_unsigned: bool = True) -> Verdict:
        """The verdict on one whole packet (checksum already verified by the framer).
        `allow_unsigned=False`: a radio's unsigned packet is refused too (it came from
        somewhere no radio of ours is)."""
        verdict = self._verdict(packet, allow_unsigned)
        counts = self.counts
        setattr(counts, verdict, getattr(counts, verdict) + 1)
        return verdict

    def _verdict(self, packet: bytes | bytearray, allow_unsigned: bool) -> Verdict:
        if packet[0] == MAGIC_V1 or not packet[2] & _IFLAG_SIGNED:
            allowed = allow_unsigned and message_id(packet) in UNSIGNED_ALLOWED
            return "unsigned_allowed" if allowed else "unsigned"
        body, sig = packet[:-6], packet[-6:]
        expected = hashlib.sha256(self._key + bytes(body)).digest()[:6]
        if not hmac.compare_digest(expected, bytes(sig)):
            return "bad_signature"
        link_id = packet[-SIGNATURE_LEN]
        stamp = int.from_bytes(packet[-12:-6], "little")
        stream = (link_id, packet[5], packet[6])
        last = self._streams.get(stream)
        if last is not None:
            if stamp <= last:
                return "replayed"
        elif stamp + _NEW_STREAM_SLACK < self._signing.timestamp:
            return "replayed"  # a new stream from more than a minute ago: a recording
        self._streams[stream] = stamp
        if stamp > self._signing.timestamp:
            self._signing.timestamp = stamp
        return "signed"


def enable_signing(mav: Any, key: bytes, link_id: int = 0) -> SignatureCheck:
    """Sign everything `mav` (a pymavlink MAVLink) packs from now on, starting from the
    wall clock's timestamp, and return the check for what comes in."""
    if len(key) != 32:
        raise ValueError("a MAVLink signing key is 32 bytes")
    s = mav.signing
    s.secret_key = key
    s.sign_outgoing = True
    s.link_id = link_id
    s.timestamp = max(s.timestamp, signing_timestamp())
    # `mav` must only pack from now on: decoding with it would run pymavlink's own check
    # (module docstring). Incoming packets go through the returned check instead.
    s.allow_unsigned_callback = None
    return SignatureCheck(s)
