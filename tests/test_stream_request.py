"""Our rate requests and other ground stations' requests that change them (pure)."""

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.companion.stream_request import StreamRequester

RATES = {"ATTITUDE": 50.0, "GPS_RAW_INT": 5.0}


def requester() -> tuple[StreamRequester, mavlink.MAVLink]:
    ours = mavlink.MAVLink(None, srcSystem=254, srcComponent=190)
    other = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    return StreamRequester(ours, RATES), other


def test_request_data_stream_from_another_gcs_is_seen_and_ours_sent_again():
    req, qgc = requester()
    req.start(0.0, 1, 1)
    req.poll(5.0)  # no answer: the legacy streams
    assert req.mode == "data_stream"
    extra1 = qgc.request_data_stream_encode(1, 1, mavlink.MAV_DATA_STREAM_EXTRA1, 2, 1)
    assert req.foreign_change(extra1, 1) == "REQUEST_DATA_STREAM stream 10 at 2 Hz"
    all_off = qgc.request_data_stream_encode(0, 0, mavlink.MAV_DATA_STREAM_ALL, 4, 0)
    assert req.foreign_change(all_off, 1) == "REQUEST_DATA_STREAM stream 0 at 0 Hz"
    extra3 = qgc.request_data_stream_encode(1, 1, mavlink.MAV_DATA_STREAM_EXTRA3, 2, 1)
    assert req.foreign_change(extra3, 1) is None  # carries nothing we need
    other_vehicle = qgc.request_data_stream_encode(2, 1, mavlink.MAV_DATA_STREAM_EXTRA1, 2, 1)
    assert req.foreign_change(other_vehicle, 1) is None
    again = req.reassert()
    assert {(m.req_stream_id, m.req_message_rate) for m in again} == {
        (mavlink.MAV_DATA_STREAM_EXTRA1, 50),
        (mavlink.MAV_DATA_STREAM_RAW_SENSORS, 5),
    }


def test_set_message_interval_by_another_gcs_and_its_ack_is_not_ours():
    req, qgc = requester()
    req.start(0.0, 1, 1)
    vehicle = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    ack_for_qgc = vehicle.command_ack_encode(
        mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAV_RESULT_ACCEPTED, 0, 0, 255, 190
    )
    req.on_ack(ack_for_qgc, 0.1)
    assert req.mode == "waiting"  # someone else's answer
    ack = vehicle.command_ack_encode(
        mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAV_RESULT_ACCEPTED, 0, 0, 254, 190
    )
    req.on_ack(ack, 0.2)
    assert req.mode == "message_interval"
    cut = qgc.command_long_encode(
        1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mavlink.MAVLINK_MSG_ID_ATTITUDE,
        -1, 0, 0, 0, 0, 0,
    )  # fmt: skip
    assert req.foreign_change(cut, 1) == "SET_MESSAGE_INTERVAL ATTITUDE off"
    unrelated = qgc.command_long_encode(
        1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mavlink.MAVLINK_MSG_ID_VIBRATION,
        1e5, 0, 0, 0, 0, 0,
    )  # fmt: skip
    assert req.foreign_change(unrelated, 1) is None
    again = req.reassert()
    assert {(int(m.param1), m.param2) for m in again} == {
        (mavlink.MAVLINK_MSG_ID_ATTITUDE, 20_000.0),
        (mavlink.MAVLINK_MSG_ID_GPS_RAW_INT, 200_000.0),
    }
    assert req.mode == "message_interval"
