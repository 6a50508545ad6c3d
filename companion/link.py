"""The MAVLink link to the vehicle: one thread owns the port, everyone else reads snapshots.

The thread reads bytes, cuts them into packets (`MavFramer`), hands every raw packet on
the link to the packet listeners (the recorder: what the vehicle sent, what we sent and
what the ground stations we forward to sent, as QGroundControl's tlogs hold), merges the
autopilot's messages into the `VehicleState` (`StateTracker`) and publishes each new
state through `link.state` (`Latest`). It also sends the GCS heartbeat, asks for message
rates, reconnects when the port or peer goes away, and flags `link_lost` after
`link_lost_s` without an autopilot heartbeat. When another ground station changes the rates we asked for, it says so in the
health report and asks again. Nothing here ever runs on the event loop: `send()` only
queues and wakes.

Who may feed it: a UDP link hears only its peer (`companion.transports.UdpTransport`), and
with `signing_key_file` set every packet we send is signed and every packet that comes in
must carry a good signature (`core.mavlink.signing`); what is refused never reaches the
state, the recording or the forward targets, and is counted in `health().security`.
"""

from __future__ import annotations

import collections
import logging
import os
import selectors
import threading
import time
from collections.abc import Callable
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.companion.forward_resolver import ForwardResolver
from fpv_station.companion.latest import Latest
from fpv_station.companion.link_health import HealthMeter, LinkHealth, LinkSecurity, RateChange
from fpv_station.companion.link_settings import LinkSettings
from fpv_station.companion.source_clock import SourceClock
from fpv_station.companion.state_tracker import StateTracker
from fpv_station.companion.stream_request import StreamRequester
from fpv_station.companion.timesync import TimeSync
from fpv_station.companion.transports import (
    ConnectionStringError,
    ConnSpec,
    ForeignSenders,
    Transport,
    UdpTransport,
    format_addr,
    is_ip_address,
    open_transport,
    parse_connection,
)
from fpv_station.companion.vehicle_state import VehicleState
from fpv_station.core.mavlink.framing import MavFramer, packet_version, payload
from fpv_station.core.mavlink.signing import (
    SignatureCheck,
    Verdict,
    enable_signing,
    mavproxy_reads_differently,
    read_passphrase,
)
from fpv_station.core.mavlink.tlog_records import TlogReader

log = logging.getLogger(__name__)

PacketListener = Callable[[float, bytes], None]
_TICK_S = 0.05  # the longest the thread sleeps between housekeeping passes
_OUTBOX_MAX = 256  # queued outgoing messages; the oldest go first when full
# Ask for our rates again this long after another GCS changed them: after its burst of
# requests has reached the autopilot, so that ours arrive last.
_REASSERT_DELAY_S = 0.3
_RATE_REQUESTS = frozenset({"COMMAND_LONG", "COMMAND_INT", "REQUEST_DATA_STREAM"})


class MavlinkLink:
    """Owns the vehicle connection described by `settings.source` (not "none"/"sim")."""

    def __init__(self, settings: LinkSettings, source: str | None = None) -> None:
        self.settings = settings
        self.spec = parse_connection(source or settings.source)
        if self.spec.kind in ("none", "sim"):
            raise ConnectionStringError(f"'{self.spec.text}' is not a vehicle connection.")
        self._forward_specs = [parse_connection(f) for f in settings.forward]
        for spec in self._forward_specs:
            if spec.kind not in ("udpin", "udpout"):
                raise ConnectionStringError(
                    f"--forward '{spec.text}' must be udpout:HOST:PORT or udpin:HOST:PORT."
                )
        self.mav = mavlink.MAVLink(
            None, srcSystem=settings.gcs_sysid, srcComponent=settings.gcs_compid
        )
        # Signing guards a live link; a replay's packets are what was recorded, as it was.
        key = settings.signing_key() if self.spec.kind != "replay" else None
        self._signing: SignatureCheck | None = enable_signing(self.mav, key) if key else None
        # What the --forward ground stations send the vehicle: the same key and clock,
        # its own streams and counts.
        self._forward_signing = SignatureCheck(self.mav.signing) if key else None
        if key and settings.signing_key_file is not None:
            mismatch = mavproxy_reads_differently(read_passphrase(settings.signing_key_file))
            if mismatch:
                log.warning("%s: %s", settings.signing_key_file, mismatch)
        self._foreign = ForeignSenders()
        self._forward_foreign = ForeignSenders()
        self._next_foreign_log = 1  # log foreign senders at 1, 10, 100, ... datagrams
        self.state: Latest[VehicleState] = Latest(VehicleState())
        # A replay runs on its own clock (the log's); a live vehicle on the station's.
        self.clock = SourceClock(own=self.spec.kind == "replay")
        self._tracker = StateTracker(settings.sysid, gcs_sysid=settings.gcs_sysid)
        self._framer = MavFramer()
        self._state_changed = False  # the tracker's state is newer than the one published
        self._meter = HealthMeter(self.spec.text)
        self._streams = StreamRequester(self.mav, settings.message_rates_hz)
        # The vehicle's boot clock on ours (companion.timesync): asked on a live link,
        # read back from the recorded exchange in a replay.
        self.timesync = TimeSync(enabled=settings.timesync_hz > 0 or self.spec.kind == "replay")
        self._next_timesync = 0.0
        self._listeners: list[PacketListener] = []
        self._outbox: collections.deque[mavlink.MAVLink_message] = collections.deque(
            maxlen=_OUTBOX_MAX
        )
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._stop = threading.Event()
        self._pipe_closed = False
        self._thread: threading.Thread | None = None
        # What killed the link thread (None while it lives or ended as it should): the
        # station's health and systemd watchdog read it, so a dead link is restarted.
        self.crashed: str | None = None
        self._transport: Transport | None = None
        self._forwarders: list[UdpTransport] = []
        self._forward_framers: dict[UdpTransport, MavFramer] = {}
        self._resolver = ForwardResolver([], self.settings.forward_resolve_s)
        self._reassert_at: float | None = None
        self._last_hb_mono: float | None = None
        self._next_gcs_hb = 0.0
        self._force_v1 = False
        self._listener_errors = 0
        self._own_identity_packets = 0  # from the link in our sysid/compid

    # -- public interface ---------------------------------------------------------

    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError("MavlinkLink already started")
        self._forwarders = []
        named: list[tuple[ConnSpec, UdpTransport]] = []
        for spec in self._forward_specs:
            try:
                # A name is looked up by the resolver's thread, not here (the event loop).
                fwd = UdpTransport(
                    spec, self.settings.udpin_lock, self._forward_foreign, resolve_name=False
                )
            except OSError as exc:  # the port is taken: the vehicle still flies
                self._meter.last_error = f"--forward {spec.text}: {exc}; not forwarding there"
                log.error("%s", self._meter.last_error)
                continue
            self._forwarders.append(fwd)
            if spec.kind == "udpout" and not is_ip_address(spec.host):
                named.append((spec, fwd))
        self._forward_framers = {fwd: MavFramer() for fwd in self._forwarders}
        self._resolver = ForwardResolver(named, self.settings.forward_resolve_s)
        self._resolver.start()
        self._thread = threading.Thread(
            target=self._run, name=f"mavlink {self.spec.text}", daemon=True
        )
        self._thread.start()

    def stop(self, timeout: float = 3.0) -> None:
        self._stop.set()
        self._resolver.stop()
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout)
        self.state.close()
        if self._thread is not None and self._thread.is_alive():
            log.error("MAVLink link thread did not stop within %.1f s", timeout)
            return  # leave its fds open rather than pull them from under it
        for fwd in self._forwarders:
            fwd.close()
        if not self._pipe_closed:  # twice would close fd numbers the OS may have reused
            self._pipe_closed = True
            os.close(self._wake_r)
            os.close(self._wake_w)

    def add_packet_listener(self, cb: PacketListener) -> None:
        """`cb(t_wall_s, packet)` runs in the link thread for every good packet; it must
        not block (put into a bounded buffer and return)."""
        self._listeners = [*self._listeners, cb]  # copy-on-write: the thread iterates safely

    def remove_packet_listener(self, cb: PacketListener) -> None:
        """Stop calling `cb` (compared by equality: a bound method is a new object each
        time it is looked up)."""
        self._listeners = [x for x in self._listeners if x != cb]

    def send(self, msg: mavlink.MAVLink_message) -> None:
        """Queue a message for the vehicle; thread-safe and never blocks. Build it with
        `link.mav.<name>_encode(...)`. Dropped (oldest first) if the port is down long."""
        self._outbox.append(msg)
        self._wake()

    def autopilot(self) -> tuple[int, int] | None:
        """The followed autopilot's (sysid, compid), the target of our commands to it; None
        before one is heard."""
        sysid, compid = self._tracker.sysid, self._tracker.compid
        return None if sysid is None or compid is None else (sysid, compid)

    def health(self) -> LinkHealth:
        return self._meter.report(
            self._framer.counters,
            state.value.link.link_lost if (state := self.state.get()) else True,
            self._last_hb_mono,
            self.clock.mono(),
            self._tracker.sysid if self._tracker.compid is not None else self._tracker.pinned_sysid,
            self._tracker.compid,
            self._security(),
            self._resolver.targets(),
        )

    def _security(self) -> LinkSecurity:
        transport = self._transport
        peer = transport.peer if isinstance(transport, UdpTransport) else None
        counts = self._signing.counts if self._signing is not None else None
        fwd = self._forward_signing.counts if self._forward_signing is not None else None
        return LinkSecurity(
            peer=format_addr(peer),
            udpin_lock=self.settings.udpin_lock,
            foreign_datagrams=self._foreign.datagrams,
            last_foreign_sender=format_addr(self._foreign.last),
            forward_foreign_datagrams=self._forward_foreign.datagrams,
            signing=counts is not None,
            signed=counts.signed if counts else 0,
            unsigned_allowed=counts.unsigned_allowed if counts else 0,
            unsigned_refused=counts.unsigned if counts else 0,
            bad_signature_refused=counts.bad_signature if counts else 0,
            replay_refused=counts.replayed if counts else 0,
            forward_signed=fwd.signed if fwd else 0,
            forward_unsigned_refused=fwd.unsigned if fwd else 0,
            forward_bad_signature_refused=fwd.bad_signature if fwd else 0,
            forward_replay_refused=fwd.replayed if fwd else 0,
            own_identity_packets=self._own_identity_packets,
        )

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # -- the thread ------------------------------------------------------------------

    def _wake(self) -> None:
        if self._pipe_closed:
            return  # never write to a closed fd number: the OS may have reused it
        try:
            os.write(self._wake_w, b"\0")
        except (BlockingIOError, OSError):
            pass  # pipe full (already woken) or closed (stopping)

    def _run(self) -> None:
        try:
            if self.spec.kind == "replay":
                self._run_replay()
            else:
                self._run_live()
        except Exception as exc:  # a bug must show in the log and the health, not vanish
            log.exception("MAVLink link thread died")
            self.crashed = f"{type(exc).__name__}: {exc}"
            self._meter.last_error = "link thread crashed; see the station's log"
            self._meter.connected = False

    def _run_live(self) -> None:
        first = True
        while not self._stop.is_set():
            if not first:
                self._meter.reconnects += 1
                self._idle(self.settings.reconnect_s)
                if self._stop.is_set():
                    return
            first = False
            try:
                transport = open_transport(self.spec, self.settings.udpin_lock, self._foreign)
            except OSError as exc:
                self._meter.last_error = f"cannot open {self.spec.text}: {exc}"
                log.warning("%s", self._meter.last_error)
                continue
            self._transport = transport
            if isinstance(transport, UdpTransport):
                transport.confirm_senders = self._signing is not None
                transport.probation_after_s = self.settings.link_lost_s
            self._meter.connected = True
            self._framer.reset()
            self._meter.on_reconnect()
            self._next_gcs_hb = 0.0
            self._streams.mode = "none"
            log.info("MAVLink connected: %s", self.spec.text)
            try:
                self._serve(transport)
            except OSError as exc:  # includes ConnectionError and pyserial's SerialException
                self._meter.last_error = f"{self.spec.text}: {exc}"
                log.warning("MAVLink connection lost: %s", self._meter.last_error)
            finally:
                self._meter.connected = False
                self._transport = None
                transport.close()

    def _serve(self, transport: Transport) -> None:
        # A udpin sender waiting to be confirmed by a signed packet; TCP and serial have
        # one peer by construction, so there is no one to confirm.
        confirm = (
            transport if isinstance(transport, UdpTransport) and transport.confirm_senders else None
        )
        # epoll, not select(): the station raises its file limit for its clients, and
        # select() cannot watch a descriptor numbered 1024 or more (ValueError).
        transport_fd = transport.fileno()
        forwarders = {fwd.fileno(): fwd for fwd in self._forwarders}
        with selectors.DefaultSelector() as selector:
            for fd in (transport_fd, self._wake_r, *forwarders):
                selector.register(fd, selectors.EVENT_READ)
            next_housekeeping = 0.0
            while not self._stop.is_set():
                ready = selector.select(_TICK_S)
                now = time.monotonic()
                for key, _ in ready:
                    if key.fd == transport_fd:
                        for data in transport.read_queued():
                            probation = confirm is not None and confirm.probation
                            if data and self._on_bytes(data, now, probation) and confirm:
                                confirm.adopt_sender()
                    elif key.fd == self._wake_r:
                        try:
                            os.read(self._wake_r, 4096)
                        except BlockingIOError:
                            pass
                    else:  # a forward peer (QGroundControl) talks back: pass it on
                        peer = forwarders[key.fd]
                        data = peer.read()
                        if data:
                            self._on_forwarded(peer, data, now, transport)
                self._publish_state()
                while self._outbox:
                    self._write(transport, self._outbox.popleft())
                # Once a tick, not after every packet (140 a second): what it does is due
                # at 1 Hz (our heartbeat) or after seconds (link lost, stream requests).
                if now >= next_housekeeping:
                    next_housekeeping = now + _TICK_S
                    self._housekeeping(transport, now)

    def _run_replay(self) -> None:
        path = Path(self.spec.path)
        if not path.is_file():
            self._meter.last_error = f"replay file {path} does not exist"
            log.error("%s", self._meter.last_error)
            self._idle_forever()
            return
        reader = TlogReader(path)
        self._meter.connected = True
        clock = self.clock
        for segment, records in reader.segments():
            if segment > 0:
                self._next_recording(reader)
            t0_rec: float | None = None
            t0_mono = time.monotonic()
            for t_rec, packet in records:
                if self._stop.is_set():
                    return
                if t0_rec is None:
                    t0_rec = t_rec
                if self.spec.speed > 0:
                    due = t0_mono + (t_rec - t0_rec) / self.spec.speed
                    while (wait := due - time.monotonic()) > 0 and not self._stop.is_set():
                        self._stop.wait(min(wait, _TICK_S))
                        # Between records the log's clock runs with the wall clock (x
                        # speed), so a silence in the log is a silence as it passes.
                        now = t_rec - max(due - time.monotonic(), 0.0) * self.spec.speed
                        clock.advance(now)
                        self._housekeeping(None, clock.mono())
                clock.advance(t_rec)  # listeners see the time before the record applies
                self._on_bytes(packet, clock.mono())
                self._publish_state()
                self._housekeeping(None, clock.mono())
        self._meter.truncated_records = reader.truncated
        self._meter.replay_done = True
        self._meter.connected = False
        # Nothing more will come from this vehicle: say so, and end what follows it.
        now = clock.mono()
        self._state_changed |= self._tracker.set_link_lost(True, now, self._last_hb_mono)
        self._publish_state()
        clock.end()
        log.info("replay of %s done (%d truncated records)", path, reader.truncated)
        self._idle_forever()

    def _next_recording(self, reader: TlogReader) -> None:
        """The replayed log's clock stepped back: another recording joined to it begins.
        The one before ends as a replay ends (link lost; the clock's listeners told, so
        the recorder closes its session), and the vehicle is heard anew, on the new
        recording's clock, from a state that knows nothing yet (not armed: an armed
        start of the next recording is an arming, and starts its own session)."""
        step = reader.clock_steps[-1]
        log.warning(
            "replay of %s: the log's clock steps back %.1f s at record %d; "
            "playing it as another recording",
            self.spec.path,
            step.from_s - step.to_s,
            step.record,
        )
        now = self.clock.mono()
        self._state_changed |= self._tracker.set_link_lost(True, now, self._last_hb_mono)
        self._publish_state()
        self.clock.step_back()
        self.timesync.reset()
        self._tracker = StateTracker(self.settings.sysid, gcs_sysid=self.settings.gcs_sysid)
        self._last_hb_mono = None
        self._framer.reset()
        self._meter.on_clock_step_back()
        self._state_changed = True
        self._publish_state()

    def _idle(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while not self._stop.is_set() and (left := deadline - time.monotonic()) > 0:
            self._stop.wait(min(left, _TICK_S))
            self._housekeeping(None, self.clock.mono())

    def _idle_forever(self) -> None:
        while not self._stop.is_set():
            self._idle(1.0)

    # -- per packet and periodic work -------------------------------------------------

    def _on_bytes(self, data: bytes, now: float, probation: bool = False) -> int:
        """Handle what arrived; returns how many packets confirm its sender as the peer:
        those with a good signature, and from a host on `probation` (not the udpin
        lock's; signing on) only the followed autopilot's, whose unsigned radio packets
        are refused there too. The new state is published by `_publish_state`, once for
        all that one wake-up read."""
        self._meter.on_bytes(len(data))
        msgs = self._framer.feed(data)
        if not msgs:
            return 0
        signed = 0
        t_wall = self.clock.wall()  # a replay's packets keep their log times
        tracker = self._tracker
        changed = False
        # A replay holds what the station itself sent: its own identity is no clash there.
        own = (self.mav.srcSystem, self.mav.srcComponent) if self.spec.kind != "replay" else None
        for msg in msgs:
            if own is not None and (msg.get_srcSystem(), msg.get_srcComponent()) == own:
                self._on_own_identity(msg)
                if self._signing is not None:
                    continue  # never ours to hear, nor a vehicle's: refused unchecked
            packet = bytes(msg.get_msgbuf())
            if self._signing is not None:
                verdict = self._check_signature(packet, allow_unsigned=not probation)
                if verdict not in ("signed", "unsigned_allowed"):
                    continue  # not the vehicle's: kept out of the state, recording, forwards
                # Another key holder elsewhere (a signed MAVProxy) must not take the lock.
                signed += verdict == "signed" and (not probation or tracker.follows(msg))
            mtype = msg.get_type()
            self._meter.on_packet(mtype, msg.get_srcSystem(), msg.get_srcComponent(), msg.get_seq())
            if mtype == "HEARTBEAT" and msg.type == mavlink.MAV_TYPE_GCS:
                self._on_gcs_heartbeat(msg)
            elif mtype in _RATE_REQUESTS:
                self._check_rate_request(msg, now, "link")
            elif mtype == "TIMESYNC":
                self._on_timesync(msg, now)
            self._notify(t_wall, packet)
            for fwd in self._forwarders:
                fwd.write(packet)
            if tracker.update(msg, now):
                changed = True
                if mtype == "HEARTBEAT":
                    self._on_autopilot_heartbeat(now, packet_version(msg) == 1)
            # Acks of our stream requests also go into the state (vehicle messages).
            if mtype == "COMMAND_ACK" and self._transport is not None:
                for req in self._streams.on_ack(msg, now):
                    self._write(self._transport, req)
        self._state_changed |= changed
        return signed

    def _publish_state(self) -> None:
        if self._state_changed:
            self._state_changed = False
            self.state.publish(self._tracker.state)

    def _check_signature(self, packet: bytes, allow_unsigned: bool = True) -> Verdict:
        assert self._signing is not None
        verdict = self._signing.check(packet, allow_unsigned)
        if verdict in ("signed", "unsigned_allowed"):
            return verdict
        c = self._signing.counts
        refused = c.refused
        if refused in (1, 10, 100, 1000) or refused % 10000 == 0:
            log.warning(
                "MAVLink signing refused %d packets (%d unsigned, %d bad signature, "
                "%d replayed); latest: %s",
                refused,
                c.unsigned,
                c.bad_signature,
                c.replayed,
                verdict,
            )
        return verdict

    def _notify(self, t_wall: float, packet: bytes) -> None:
        for cb in self._listeners:
            try:
                cb(t_wall, packet)
            except Exception:
                self._listener_errors += 1
                if self._listener_errors in (1, 10, 100, 1000):
                    log.exception("packet listener %r failed (%d times)", cb, self._listener_errors)

    def _on_forwarded(
        self, peer: UdpTransport, data: bytes, now: float, transport: Transport
    ) -> None:
        """What a ground station we forward to sent the vehicle: passed on, recorded, and
        watched for requests that change our rates. With signing on, each packet's
        signature is checked and counted first, as the link's are: a refused one is
        neither passed on nor recorded (the vehicle would refuse it too, and a ground
        station whose key differs shows in the counts instead of failing silently)."""
        check = self._forward_signing
        if check is None:
            transport.write(data)  # as it came, in one write
        t_wall = time.time()
        for msg in self._forward_framers[peer].feed(data):
            if check is not None:
                packet = bytes(msg.get_msgbuf())
                if check.check(packet) not in ("signed", "unsigned_allowed"):
                    continue
                transport.write(packet)
            mtype = msg.get_type()
            if mtype == "HEARTBEAT" and msg.type == mavlink.MAV_TYPE_GCS:
                self._on_gcs_heartbeat(msg)
            elif mtype in _RATE_REQUESTS:
                self._check_rate_request(msg, now, "forward")
            self._notify(t_wall, bytes(msg.get_msgbuf()))

    def _on_timesync(self, msg: mavlink.MAVLink_message, now: float) -> None:
        """A TIMESYNC on the link (companion.timesync): an answer to us from the followed
        autopilot is a round trip; in a replay, our recorded request is when it was sent."""
        me = (self.mav.srcSystem, self.mav.srcComponent)
        if msg.tc1 == 0:  # a request: the vehicle's own, another asker's, or our recorded one
            if self.spec.kind == "replay" and (msg.get_srcSystem(), msg.get_srcComponent()) == me:
                self.timesync.sent(msg.ts1, now)
            return
        if not self._tracker.follows(msg) or self._tracker.compid is None:
            self.timesync.ignored += 1  # another system's answer (a companion computer's)
            return
        # target_system and target_component: extension bytes 16 and 17 of the payload
        # (newer than pymavlink's dialect), 0 when absent (MAVLink 1, older firmware).
        ext = payload(msg.get_msgbuf())[16:18].ljust(2, b"\0")
        to = (ext[0], ext[1])
        if to != (0, 0) and to != me:
            self.timesync.ignored += 1  # the vehicle answering another ground station
            return
        self.timesync.answered(msg.tc1, msg.ts1, now)

    def _send_timesync(self, transport: Transport, now: float) -> None:
        self._next_timesync = now + 1.0 / self.settings.timesync_hz
        ts1 = time.monotonic_ns()
        # Broadcast, as pymavlink's dialect has no target fields: the autopilot answers
        # any request, a companion computer may too (told apart by their answers).
        msg = self.mav.timesync_encode(0, ts1)
        self.timesync.sent(ts1, self.clock.mono())
        self._write(transport, msg)

    def _on_own_identity(self, msg: mavlink.MAVLink_message) -> None:
        """A packet from the link in our own system and component id: another ground
        station configured as we are, or our packets sent back to us. Either way what
        the vehicle hears from "us" is not only ours: an identity clash."""
        self._own_identity_packets += 1
        if not self._meter.gcs_identity_clash:
            log.warning(
                "packets from the link carry our identity %d/%d (%s): set link.gcs_sysid%s",
                msg.get_srcSystem(),
                msg.get_srcComponent(),
                msg.get_type(),
                "; refused while signing is on" if self._signing is not None else "",
            )
        self._meter.gcs_identity_clash = True

    def _on_gcs_heartbeat(self, msg: mavlink.MAVLink_message) -> None:
        sysid, compid = msg.get_srcSystem(), msg.get_srcComponent()
        self._meter.loss.note_gcs(sysid, compid)
        if (sysid, compid) == (self.mav.srcSystem, self.mav.srcComponent):
            if not self._meter.gcs_identity_clash:
                log.warning(
                    "another ground station uses our identity %d/%d: set link.gcs_sysid",
                    sysid,
                    compid,
                )
            self._meter.gcs_identity_clash = True

    def _check_rate_request(self, msg: mavlink.MAVLink_message, now: float, via: str) -> None:
        sysid, compid = msg.get_srcSystem(), msg.get_srcComponent()
        if (sysid, compid) == (self.mav.srcSystem, self.mav.srcComponent):
            return  # our own request, echoed by a shared network
        autopilot = self._tracker.sysid if self._tracker.compid is not None else None
        if sysid == autopilot:
            return  # the vehicle's own components talking among themselves
        what = self._streams.foreign_change(msg, autopilot)
        if what is None:
            return
        self._meter.rate_changes_by_others += 1
        self._meter.last_rate_change = RateChange(time.time(), sysid, compid, what, via)
        log.warning("ground station %d/%d changed our rates: %s", sysid, compid, what)
        if self.settings.request_streams:
            self._reassert_at = now + _REASSERT_DELAY_S

    def _on_autopilot_heartbeat(self, now: float, mavlink1: bool) -> None:
        self._last_hb_mono = now
        self._force_v1 = mavlink1
        if self._tracker.state.link.link_lost:
            self._tracker.set_link_lost(False, now, now)
            # (Re)gained the autopilot: (re)ask for our rates; it may have rebooted.
            if self._transport is not None and self.settings.request_streams:
                target = (self._tracker.sysid or 0, self._tracker.compid or 0)
                for req in self._streams.start(now, *target):
                    self._write(self._transport, req)
        else:
            self._tracker.set_link_lost(False, self._tracker.state.link.t_mono or now, now)

    def _housekeeping(self, transport: Transport | None, now: float) -> None:
        if transport is not None:
            if now >= self._next_gcs_hb:
                self._next_gcs_hb = now + 1.0 / self.settings.heartbeat_hz
                hb = self.mav.heartbeat_encode(
                    mavlink.MAV_TYPE_GCS,
                    mavlink.MAV_AUTOPILOT_INVALID,
                    0,
                    0,
                    mavlink.MAV_STATE_ACTIVE,
                )
                self._write(transport, hb)
            for req in self._streams.poll(now):
                self._write(transport, req)
            heard = self._tracker.compid is not None and not self._tracker.state.link.link_lost
            if heard and self.settings.timesync_hz > 0 and now >= self._next_timesync:
                self._send_timesync(transport, now)
            if self._reassert_at is not None and now >= self._reassert_at:
                self._reassert_at = None
                requests = self._streams.reassert()
                for req in requests:
                    self._write(transport, req)
                self._meter.rates_reasserted += bool(requests)
        self._meter.stream_request = self._streams.mode
        foreign = self._foreign.datagrams + self._forward_foreign.datagrams
        if foreign >= self._next_foreign_log:
            self._next_foreign_log = foreign * 10
            last = self._foreign.last or self._forward_foreign.last
            log.warning(
                "dropped %d UDP datagrams from senders other than the link's peer; latest from %s",
                foreign,
                format_addr(last),
            )
        lost = self._last_hb_mono is None or now - self._last_hb_mono > self.settings.link_lost_s
        if lost and not self._tracker.state.link.link_lost:
            self._state_changed |= self._tracker.set_link_lost(True, now, self._last_hb_mono)
            self._publish_state()
            log.warning("link lost: no autopilot heartbeat for %.1f s", self.settings.link_lost_s)
        self._meter.tick(now)

    def _write(self, transport: Transport, msg: mavlink.MAVLink_message) -> None:
        # MAVLink 1 cannot carry a signature: a signed link speaks MAVLink 2 only.
        v1 = self._force_v1 and self._signing is None
        packet = bytes(msg.pack(self.mav, force_mavlink1=v1))
        transport.write(packet)
        self.mav.seq = (self.mav.seq + 1) % 256
        self._notify(self.clock.wall(), packet)  # what we sent belongs in the recording too
