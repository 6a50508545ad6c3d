"""The MAVLink log protocol against real bytes: a real DataFlash log (tests/data/dataflash)
served by a test vehicle over a real UDP socket, fetched by the station's link and
`companion.onboard_log.LogDownload`; and the twin's own ULog served the same way."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from pymavlink import DFReader
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from pyulog import ULog

from fpv_station.companion.link import MavlinkLink
from fpv_station.companion.link_settings import LinkSettings
from fpv_station.companion.onboard_log import (
    DownloadStatus,
    LinkLike,
    LogDownload,
    LogEntry,
    OnboardLogSettings,
    choose_log,
    log_file_name,
)
from fpv_station.core.mavlink.framing import message_id
from fpv_station.twin.runner import Twin
from tests.helpers import wait_until
from tests.log_responder import CHUNK, LogResponder

DATAFLASH = Path(__file__).parent / "data" / "dataflash" / "arducopter.bin"
# Short retries: a lost window is asked for again within a fraction of a second; the
# give-up stays long, so a loaded machine only retries more, never gives up early.
FAST = {"request_timeout_s": 0.3, "give_up_s": 60.0}


@pytest.fixture
def dataflash() -> bytes:
    return DATAFLASH.read_bytes()


def _link(source: str) -> MavlinkLink:
    link = MavlinkLink(LinkSettings(source=source, request_streams=False))
    link.start()
    return link


@pytest.fixture
def served(
    dataflash: bytes, request: pytest.FixtureRequest
) -> Iterator[tuple[LogResponder, MavlinkLink]]:
    kwargs = getattr(request, "param", {})
    logs = kwargs.pop("logs", {1: b"an older log" * 50, 2: dataflash})
    with LogResponder(logs, **kwargs) as vehicle:
        link = _link(vehicle.station_source)
        try:
            assert wait_until(lambda: link.health().autopilot_sysid == 1, 20), "never heard"
            yield vehicle, link
        finally:
            link.stop()


def _download(link: LinkLike, folder: Path, timeout_s: float = 90.0, **kwargs) -> DownloadStatus:
    settings = OnboardLogSettings(**{**FAST, **kwargs.pop("settings", {})})
    dl = LogDownload(link, (1, 1), folder, settings, **kwargs)
    dl.start()
    dl.join(timeout_s)  # a hang guard: every path ends by itself
    status = dl.status.current()
    assert not dl.running, f"the download hangs: {status}"
    assert status.done
    return status


def test_served_dataflash_downloads_byte_identical(
    served, tmp_path: Path, dataflash: bytes
) -> None:
    vehicle, link = served
    status = _download(link, tmp_path)
    assert status.state == "complete", status
    assert status.log_id == 2 and status.logs_listed == 2  # the newest: the flight's
    assert status.file == "onboard.bin"
    assert (tmp_path / "onboard.bin").read_bytes() == dataflash
    assert not (tmp_path / "onboard.part").exists()
    assert status.received_bytes == status.size_bytes == len(dataflash)
    assert wait_until(lambda: vehicle.end_requests >= 1, 10)  # told the transfer is over
    # Bounded windows: nothing was asked for beyond the window size.
    window = OnboardLogSettings().window_bytes
    assert vehicle.data_requests and all(count <= window for _, _, count in vehicle.data_requests)
    # And it reads as a DataFlash log, IMU and all.
    reader = DFReader.DFReader_binary(str(tmp_path / "onboard.bin"))
    assert reader.recv_match(type="IMU") is not None


@pytest.mark.parametrize("served", [{"drop_after_bytes": 20_000, "drop_s": 2.0}], indirect=True)
def test_dropped_link_mid_download_resumes(served, tmp_path: Path, dataflash: bytes) -> None:
    vehicle, link = served
    status = _download(link, tmp_path)
    assert status.state == "complete", status
    assert (tmp_path / "onboard.bin").read_bytes() == dataflash
    assert status.re_requests >= 1
    # Resumed where it broke off, not from the start: a later request began past zero.
    assert any(ofs >= 20_000 - 90 * 128 for _, ofs, _ in vehicle.data_requests[1:])
    assert vehicle.data_requests.count((2, 0, vehicle.data_requests[0][2])) == 1


@pytest.mark.parametrize("served", [{"drop_after_bytes": 4_000, "drop_s": 2.0}], indirect=True)
def test_window_cut_short_is_asked_again_at_its_size(served, tmp_path: Path) -> None:
    """A window the link cut off is asked for again at the size it had: its rest timed
    out (six times in a 2 s fade), which says nothing of loss, so the window does not grow
    on it."""
    vehicle, link = served
    status = _download(link, tmp_path)
    assert status.state == "complete" and status.re_requests >= 1, status
    asked = [(ofs, count) for log_id, ofs, count in vehicle.data_requests if log_id == 2]
    cut = next(i for i, (ofs, count) in enumerate(asked) if ofs <= 4_000 < ofs + count)
    assert cut + 1 < len(asked), asked
    again_ofs, again_count = asked[cut + 1]
    assert asked[cut][0] < again_ofs < sum(asked[cut]), asked  # the rest of the window cut
    assert again_count <= asked[cut][1], asked


@pytest.mark.parametrize("served", [{"lose_every": 40}], indirect=True)
def test_window_shrinks_when_the_link_loses_packets(
    served, tmp_path: Path, dataflash: bytes
) -> None:
    """While the link loses the vehicle's packets, the download asks for less at a time
    (and still gets every byte); on a clean link the window grows."""
    vehicle, link = served
    status = _download(link, tmp_path)
    assert status.state == "complete", status
    assert (tmp_path / "onboard.bin").read_bytes() == dataflash
    assert status.lost_packets > 0
    # A window of 40 packets or more loses one and is halved (after it, or after the
    # next one when the loss shows only in a later packet): it never grows to the
    # largest window, which a clean link reaches (below).
    counts = [count for log_id, _, count in vehicle.data_requests if log_id == 2]
    assert max(counts) < OnboardLogSettings().window_bytes


class _HeldAfterEachRequest:
    """The station's link as the download sees it, with the download's thread held after
    each LOG_REQUEST_DATA until the link has taken in the whole window: as a loaded
    machine deschedules a thread while the link's reader runs on."""

    def __init__(self, link: MavlinkLink) -> None:
        self._link = link
        self._log_data_seen = 0
        link.add_packet_listener(self._on_packet)

    def _on_packet(self, _t_wall: float, packet: bytes) -> None:
        self._log_data_seen += message_id(packet) == mavlink.MAVLINK_MSG_ID_LOG_DATA

    @property
    def mav(self) -> mavlink.MAVLink:
        return self._link.mav

    def add_packet_listener(self, cb) -> None:
        self._link.add_packet_listener(cb)

    def remove_packet_listener(self, cb) -> None:
        self._link.remove_packet_listener(cb)

    def send(self, msg: mavlink.MAVLink_message) -> None:
        seen = self._log_data_seen
        self._link.send(msg)
        if msg.get_type() == "LOG_REQUEST_DATA":
            packets = -(-msg.count // CHUNK)
            wait_until(lambda: self._log_data_seen >= seen + packets, 10)  # a hang guard


@pytest.mark.parametrize("served", [{"lose_every": 40}], indirect=True)
def test_losses_the_link_counted_first_still_shrink_the_window(served, tmp_path: Path) -> None:
    """Losses the link counted before the download's thread ran again after its request
    still belong to that window, so the window still shrinks."""
    vehicle, link = served
    status = _download(_HeldAfterEachRequest(link), tmp_path)
    assert status.state == "complete" and status.lost_packets > 0, status
    counts = [count for log_id, _, count in vehicle.data_requests if log_id == 2]
    assert max(counts) < OnboardLogSettings().window_bytes, counts


def test_window_grows_on_a_clean_link(served, tmp_path: Path) -> None:
    """The vehicle sends one window at a time, so its packets fit the socket buffer: none
    is lost, and the window grows from a small start to `window_bytes`."""
    vehicle, link = served
    status = _download(link, tmp_path)
    assert status.state == "complete" and status.lost_packets == 0, status
    counts = [count for log_id, _, count in vehicle.data_requests if log_id == 2]
    assert counts[0] < max(counts) == OnboardLogSettings().window_bytes


@pytest.mark.parametrize("served", [{"drop_after_bytes": 20_000, "drop_s": 3600.0}], indirect=True)
def test_link_that_stays_down_ends_incomplete(served, tmp_path: Path) -> None:
    _, link = served
    status = _download(link, tmp_path, settings={"give_up_s": 2.0})
    assert status.state == "incomplete", status
    assert 0 < status.received_bytes < status.size_bytes
    assert "no data" in status.message
    assert status.file == "onboard.bin"  # what came is kept, marked incomplete
    assert (tmp_path / "onboard.bin").stat().st_size == status.size_bytes


def test_a_log_that_does_not_exist(served, tmp_path: Path) -> None:
    _, link = served
    status = _download(link, tmp_path, log_id=7)
    assert status.state == "no_log", status
    assert "log 7 is not on the vehicle" in status.message and "1, 2" in status.message
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("served", [{"logs": {}}], indirect=True)
def test_a_vehicle_without_logs(served, tmp_path: Path) -> None:
    _, link = served
    status = _download(link, tmp_path)
    assert status.state == "no_log" and status.message == "the vehicle has no logs", status


@pytest.mark.parametrize("served", [{"log_protocol": False}], indirect=True)
def test_a_vehicle_that_does_not_answer(served, tmp_path: Path) -> None:
    vehicle, link = served
    status = _download(link, tmp_path)
    assert status.state == "failed", status
    assert "did not answer LOG_REQUEST_LIST" in status.message
    assert vehicle.list_requests == 0  # it ignored them all


def test_choose_log_takes_the_newest_started_before_the_flight_ended() -> None:
    logs = [LogEntry(1, 1000, 10), LogEntry(2, 2000, 10), LogEntry(3, 9000, 10), LogEntry(4, 0, 0)]
    assert (chosen := choose_log(logs, None)) is not None and chosen.id == 3
    assert (chosen := choose_log(logs, 2500)) is not None and chosen.id == 2
    assert choose_log(logs, 500) is None
    chosen = choose_log([LogEntry(5, 0, 10)], 500)
    assert chosen is not None and chosen.id == 5  # no clock: it counts


def test_file_names() -> None:
    assert log_file_name(b"ULog\x01\x12\x35\x01") == "onboard.ulg"
    assert log_file_name(DATAFLASH.read_bytes()[:8]) == "onboard.bin"
    assert log_file_name(b"hello") == "onboard.log"


def test_twin_serves_its_ulog(tmp_path: Path) -> None:
    """The twin's vehicle serves its flight log over the same protocol and real UDP."""
    twin = Twin(mavlink="udpin:127.0.0.1:0", flight_log_dir=tmp_path / "sd")
    twin.step_for(3.0)
    assert twin.sim.arm(True)[0] and twin.sim.takeoff(2.0)[0]
    twin.step_for(3.0)
    assert twin.sim.arm(False, force=True)[0]
    twin.step_for(0.1)
    assert twin.flight_log is not None and len(twin.flight_log.logs) == 1
    twin.start()
    try:
        assert twin.vehicle is not None
        port = twin.vehicle.sock.getsockname()[1]
        link = _link(f"udpout:127.0.0.1:{port}")
        try:
            assert wait_until(lambda: link.health().autopilot_sysid == 1, 20), "never heard"
            status = _download(link, tmp_path / "session")
        finally:
            link.stop()
    finally:
        twin.stop()
    assert status.state == "complete", status
    assert status.file == "onboard.ulg"
    got = tmp_path / "session" / "onboard.ulg"
    assert got.read_bytes() == twin.flight_log.logs[0].path.read_bytes()
    assert any(d.name == "sensor_combined" for d in ULog(str(got)).data_list)
