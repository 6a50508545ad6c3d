"""How well the vehicle is heard: rates per message type, loss, throughput, junk counts.

`HealthMeter` is fed by the link thread only; `LinkHealth` is the immutable report any
thread may read. Rates come from counter snapshots taken twice a second over a ~2 s
window, so nothing is computed per packet beyond a few increments.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field

from pydantic import computed_field

from fpv_station.companion.stream_loss import StreamLoss, StreamLossCounter
from fpv_station.core.mavlink.framing import FramerCounters

_SNAPSHOT_EVERY_S = 0.5
_WINDOW_SNAPSHOTS = 5  # 4 intervals = 2 s window


@dataclass(frozen=True, slots=True)
class RateChange:
    """Another ground station asked the autopilot for other rates of messages we need."""

    t_wall: float  # Unix time, for people
    sysid: int
    compid: int
    request: str  # what it asked, in words ("SET_MESSAGE_INTERVAL ATTITUDE 2 Hz")
    via: str  # "forward" (a ground station we forward to) or "link" (one on the link)


@dataclass(frozen=True, slots=True)
class ForwardTarget:
    """A forward target's state, for the link's health."""

    target: str  # as given: "udpout:qgc-laptop.local:14550"
    address: str | None  # where its copies go now ("192.168.4.23:14550"); None: nowhere yet
    error: str | None = None  # the last lookup's failure, while it fails


@dataclass(frozen=True, slots=True)
class LinkSecurity:
    """Who may feed the link and what was refused (docs/SECURITY.md)."""

    peer: str | None = None  # UDP: the address heard and answered ("ip:port")
    udpin_lock: bool = True  # udpin hears only the first host that spoke
    foreign_datagrams: int = 0  # UDP datagrams dropped: sent by another address
    last_foreign_sender: str | None = None  # the latest such address ("ip:port")
    forward_foreign_datagrams: int = 0  # the same, on the --forward sockets
    signing: bool = False  # MAVLink 2 signing on (link.signing_key_file)
    signed: int = 0  # packets accepted with a good signature
    unsigned_allowed: int = 0  # unsigned radio packets let through (RADIO_STATUS, RADIO)
    unsigned_refused: int = 0  # refused: no signature (MAVLink 1 included)
    bad_signature_refused: int = 0  # refused: wrong key or altered bytes
    replay_refused: int = 0  # refused: good signature but an old timestamp (a replay)
    # What the --forward ground stations sent the vehicle, checked the same way: refused
    # packets are neither passed on nor recorded (a MAVProxy whose key is another's
    # shows here, as bad signatures).
    forward_signed: int = 0
    forward_unsigned_refused: int = 0
    forward_bad_signature_refused: int = 0
    forward_replay_refused: int = 0
    # Packets from the link in the station's own system and component id (another
    # ground station with our identity, or our own packets sent back): refused when
    # signing is on, counted always.
    own_identity_packets: int = 0

    # pydantic's documented form; mypy takes no decorator above @property.
    @computed_field  # type: ignore[prop-decorator]
    @property
    def refused(self) -> int:
        """Packets signing refused, all reasons (in the JSON of /api/status too: the
        pilot's OSD reads this one figure rather than adding the reasons up itself)."""
        return (
            self.unsigned_refused
            + self.bad_signature_refused
            + self.replay_refused
            + self.forward_unsigned_refused
            + self.forward_bad_signature_refused
            + self.forward_replay_refused
        )


@dataclass(frozen=True, slots=True)
class LinkHealth:
    source: str
    connected: bool  # transport open (serial port, TCP connection, socket, replay file)
    link_lost: bool  # no autopilot heartbeat for link_lost_s (or never)
    since_heartbeat_s: float | None
    autopilot_sysid: int | None
    autopilot_compid: int | None
    rates_hz: dict[str, float] = field(default_factory=dict)  # per message type, ~2 s window
    packets: int = 0  # good packets received (all systems; refused ones not included)
    lost_packets: int = 0  # the autopilot's: gaps in its sequence numbers (0 before it is heard)
    loss_ratio: float = 0.0  # the autopilot's: lost / (lost + received)
    streams: tuple[StreamLoss, ...] = ()  # loss of every sender on the link, autopilot included
    streams_untracked: int = 0  # packets of senders beyond the first 64 (a flood of identities)
    bytes_per_s: float = 0.0
    bytes_total: int = 0
    garbage_bytes: int = 0
    bad_crc: int = 0
    unknown_ids: int = 0
    truncated_records: int = 0  # replay: a last record cut short
    # replay: times the log's clock stepped back (core.mavlink.tlog_records), each the
    # start of another recording, played on its own clock
    clock_steps_back: int = 0
    reconnects: int = 0
    last_error: str | None = None
    replay_done: bool = False
    stream_request: str = "none"  # "none", "message_interval", "data_stream"
    rate_changes_by_others: int = 0  # requests by other ground stations that changed ours
    last_rate_change: RateChange | None = None
    rates_reasserted: int = 0  # times we asked for our rates again after such a change
    gcs_identity_clash: bool = False  # another ground station uses our sysid/compid
    security: LinkSecurity = field(default_factory=LinkSecurity)
    forwards: tuple[ForwardTarget, ...] = ()  # the --forward targets looked up by name


class HealthMeter:
    """Counts what the link thread sees. Only the link thread calls the `on_*` methods."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.counts: dict[str, int] = collections.defaultdict(int)
        self.bytes_total = 0
        self.loss = StreamLossCounter()
        self.truncated_records = 0
        self.clock_steps_back = 0
        self.reconnects = 0
        self.connected = False
        self.last_error: str | None = None
        self.replay_done = False
        self.stream_request = "none"
        self.rate_changes_by_others = 0
        self.last_rate_change: RateChange | None = None
        self.rates_reasserted = 0
        self.gcs_identity_clash = False
        self._snapshots: collections.deque[tuple[float, dict[str, int], int]] = collections.deque(
            maxlen=_WINDOW_SNAPSHOTS
        )
        self._rates: dict[str, float] = {}  # replaced whole, never mutated: safe to read
        self._bytes_per_s = 0.0

    def on_bytes(self, n: int) -> None:
        self.bytes_total += n

    def on_packet(self, mtype: str, sysid: int, compid: int, seq: int) -> None:
        self.counts[mtype] += 1
        self.loss.on_packet(sysid, compid, seq)

    def on_reconnect(self) -> None:
        self.loss.restart()  # a new connection starts new sequences

    def on_clock_step_back(self) -> None:
        """The source's clock started over, earlier (another recording in a replayed log):
        new sequences, and rates measured from its own times on."""
        self.clock_steps_back += 1
        self.loss.restart()
        self._snapshots.clear()

    def tick(self, t_mono: float) -> None:
        """Take a counter snapshot if due and refresh the rates from the window."""
        if self._snapshots and t_mono - self._snapshots[-1][0] < _SNAPSHOT_EVERY_S:
            return
        self._snapshots.append((t_mono, dict(self.counts), self.bytes_total))
        t0, counts0, bytes0 = self._snapshots[0]
        span = t_mono - t0
        if span <= 0:
            return
        self._rates = {
            k: round((n - counts0.get(k, 0)) / span, 2)
            for k, n in self._snapshots[-1][1].items()
            if n - counts0.get(k, 0) > 0
        }
        self._bytes_per_s = (self.bytes_total - bytes0) / span

    def report(
        self,
        framer: FramerCounters,
        link_lost: bool,
        last_heartbeat_mono: float | None,
        now_mono: float,
        sysid: int | None,
        compid: int | None,
        security: LinkSecurity,
        forwards: tuple[ForwardTarget, ...] = (),
    ) -> LinkHealth:
        streams = self.loss.report(
            (sysid, compid) if sysid is not None and compid is not None else None
        )
        autopilot = next((s for s in streams if s.role == "autopilot"), None)
        return LinkHealth(
            source=self.source,
            connected=self.connected,
            link_lost=link_lost,
            since_heartbeat_s=None
            if last_heartbeat_mono is None
            else round(now_mono - last_heartbeat_mono, 3),
            autopilot_sysid=sysid,
            autopilot_compid=compid,
            rates_hz=self._rates,
            packets=framer.packets - security.refused,  # the framer passed them, signing not
            lost_packets=autopilot.lost if autopilot else 0,
            loss_ratio=autopilot.loss_ratio if autopilot else 0.0,
            streams=streams,
            streams_untracked=self.loss.untracked,
            bytes_per_s=round(self._bytes_per_s, 1),
            bytes_total=self.bytes_total,
            garbage_bytes=framer.garbage_bytes,
            bad_crc=framer.bad_crc,
            unknown_ids=framer.unknown_ids,
            truncated_records=self.truncated_records,
            clock_steps_back=self.clock_steps_back,
            reconnects=self.reconnects,
            last_error=self.last_error,
            replay_done=self.replay_done,
            stream_request=self.stream_request,
            rate_changes_by_others=self.rate_changes_by_others,
            last_rate_change=self.last_rate_change,
            rates_reasserted=self.rates_reasserted,
            gcs_identity_clash=self.gcs_identity_clash,
            security=security,
            forwards=forwards,
        )
