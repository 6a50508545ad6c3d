"""The REST contracts, in-process: the app and its lifespan behind httpx's ASGITransport
(tests.stations.in_process), with no server, socket, twin or browser. Status and health,
OpenAPI, sessions (list, files, delete, bad ids and paths), recording (start, stop, its
refusals), the token, the analysis' one error shape, and the request guard's refusals
that are decided on a request's headers. `make test-fast` runs these alone.

What needs the network stays with a real uvicorn: a streamed zip (tests/test_sessions_api.py),
a body refused before it is read and WebSocket upgrades (tests/test_guard.py)."""

from __future__ import annotations

import os
import shutil
from collections import namedtuple

import anyio
import pytest

from tests import synthetic as syn
from tests.helpers import station_settings
from tests.stations import IN_PROCESS_BASE, StationClient, in_process

pytestmark = [pytest.mark.fast, pytest.mark.anyio]


def settings(tmp_path, **overrides):
    return station_settings("none", tmp_path / "sessions", **overrides)


async def wait_for(predicate, limit_s: float = 30.0) -> bool:
    """Await `predicate()` (a coroutine function) until true or `limit_s` (a hang guard)."""
    with anyio.move_on_after(limit_s):
        while not await predicate():  # noqa: ASYNC110 (polls the API as a client would)
            await anyio.sleep(0.02)
        return True
    return False


async def record_session(client: StationClient, rows: int = 10) -> str:
    """Start a session, let it record `rows` telemetry rows, stop it: its id."""
    r = await client.post("/api/recording/start")
    assert r.status_code == 200 and r.json()["recording"] is True
    sid = r.json()["id"]

    async def recorded() -> bool:
        return (await client.get("/api/recording")).json()["telemetry_rows"] >= rows

    assert await wait_for(recorded), "the recorder wrote no rows"
    r = await client.post("/api/recording/stop")
    assert r.status_code == 200 and r.json()["recording"] is False
    assert r.json()["last_stop"]["id"] == sid
    return sid


# ------------------------------------------------------------------ status, health, OpenAPI


async def test_status_without_a_vehicle_link(tmp_path):
    async with in_process(settings(tmp_path)) as client:
        r = await client.get("/api/status")
        assert r.status_code == 200
        body = r.json()
        assert body["source"] == "none" and body["link"] is None and body["state"] is None
        assert body["state_version"] == 0
        assert body["versions"]["fpv_station"] and body["versions"]["pymavlink"]


async def test_health_an_unknown_path_and_the_pages(tmp_path):
    async with in_process(settings(tmp_path)) as client:
        r = await client.get("/api/health")
        assert r.status_code == 200 and r.json()["ok"] is True
        missing = await client.get("/api/does-not-exist")
        assert missing.status_code == 404 and missing.json()["error"] == "HTTPError"
        page = await client.get("/")
        assert page.status_code == 200 and "text/html" in page.headers["content-type"]
        # The pilot page loads its scripts, and the telemetry feed they share opens the socket.
        assert '<script type="module" src="/flight-state.js">' in page.text
        assert (await client.get("/flight-state.js")).status_code == 200
        assert "/ws/telemetry" in (await client.get("/telemetry.js")).text


async def test_openapi_documents_every_endpoint_with_models(tmp_path):
    async with in_process(settings(tmp_path)) as client:
        spec = (await client.get("/openapi.json")).json()
        for path in ("/api/health", "/api/status"):
            ok = spec["paths"][path]["get"]["responses"]["200"]["content"]["application/json"]
            assert "$ref" in ok["schema"], path
        schemas = spec["components"]["schemas"]
        assert "LinkHealth" in schemas and "VehicleState" in schemas
        assert "relative_alt_m" in schemas["PilotAltitude"]["properties"]
        assert {"/api/sessions", "/api/recording/start", "/api/analysis"} <= set(spec["paths"])


# ------------------------------------------------------------------ sessions and recording


async def test_record_list_meta_and_files(tmp_path):
    root = tmp_path / "sessions"
    async with in_process(settings(tmp_path)) as client:
        assert (await client.get("/api/recording")).json()["recording"] is False
        sid = await record_session(client)
        listed = (await client.get("/api/sessions")).json()
        assert [s["id"] for s in listed] == [sid]
        assert listed[0]["status"] == "complete" and listed[0]["size_bytes"] > 0
        assert listed[0]["telemetry_rows"] >= 10
        detail = (await client.get(f"/api/sessions/{sid}")).json()
        assert detail["meta"]["quality"]["telemetry_rate_hz"] == 30.0
        # The test app's cameras show NO SIGNAL (no source): no frame, but their
        # frames.csv and (empty) frame packs.
        assert set(detail["files"]) == {
            "session.json",
            "telemetry.csv",
            "mavlink.tlog",
            "messages.csv",
            "front/frames.csv",
            "bottom/frames.csv",
            "front/frames.mjpeg",
            "bottom/frames.mjpeg",
        }
        assert detail["frame_files"] == {"front": 0, "bottom": 0}
        r = await client.get(f"/api/sessions/{sid}/files/telemetry.csv")
        assert r.status_code == 200 and r.content == (root / sid / "telemetry.csv").read_bytes()
        assert r.content.startswith(b"t_s,wall_time,heartbeat.t_mono")


async def test_delete_and_refused_while_recording(tmp_path):
    root = tmp_path / "sessions"
    async with in_process(settings(tmp_path)) as client:
        sid = await record_session(client, rows=1)
        live = (await client.post("/api/recording/start")).json()["id"]
        again = await client.post("/api/recording/start")  # a no-op while one records
        assert again.status_code == 200 and again.json()["id"] == live
        r = await client.delete(f"/api/sessions/{live}")
        assert r.status_code == 409 and r.json()["error"] == "Conflict"
        listed = {s["id"]: s for s in (await client.get("/api/sessions")).json()}
        assert listed[live]["recording_now"] is True and listed[live]["status"] == "recording"
        await client.post("/api/recording/stop")
        stopped = await client.post("/api/recording/stop")  # a no-op when none records
        assert stopped.status_code == 200 and stopped.json()["recording"] is False
        assert (await client.delete(f"/api/sessions/{sid}")).json() == {"deleted": sid}
        assert not (root / sid).exists()
        assert (await client.get(f"/api/sessions/{sid}")).status_code == 404


@pytest.mark.parametrize(
    "path,status",
    [
        ("/api/sessions/..%2F..%2Fetc", 404),  # a slash never matches the id: no route
        ("/api/sessions/nope", 400),
        ("/api/sessions/20200101T000000Z_sim", 404),
        ("/api/sessions/20200101T000000Z_sim/download", 404),
        ("/api/sessions/%00", 400),
    ],
)
async def test_bad_ids_rejected(tmp_path, path, status):
    async with in_process(settings(tmp_path)) as client:
        r = await client.get(path)
        assert r.status_code == status
        assert r.json()["error"] in ("BadRequest", "NotFound", "HTTPError")


async def test_traversal_rejected(tmp_path):
    root = tmp_path / "sessions"
    async with in_process(settings(tmp_path)) as client:
        sid = await record_session(client, rows=1)
        (tmp_path / "secret.txt").write_text("TOPSECRET")
        for path in (
            "..%2F..%2Fsecret.txt",
            "%2E%2E/%2E%2E/secret.txt",
            "%2Fetc%2Fpasswd",
            "a%00b",
            "front/..%2F..%2F..%2Fsecret.txt",
            "..%5C..%5Csecret.txt",
        ):
            r = await client.get(f"/api/sessions/{sid}/files/{path}")
            assert r.status_code == 400, (path, r.status_code)
            assert b"TOPSECRET" not in r.content
        assert (await client.get(f"/api/sessions/{sid}/files/front/0001.jpg")).status_code == 404
        r = await client.delete("/api/sessions/..%2F..")
        assert 400 <= r.status_code < 500
        assert root.exists() and (tmp_path / "secret.txt").exists()


async def test_token_guards_control_and_leaves_reading_open(tmp_path):
    async with in_process(settings(tmp_path, **{"server.token": "s3cret"})) as client:
        assert (await client.get("/api/recording")).status_code == 200
        assert (await client.get("/api/sessions")).status_code == 200
        r = await client.post("/api/recording/start")
        assert r.status_code == 401 and r.json()["error"] == "Unauthorized"
        bad = {"Authorization": "Bearer nope"}
        assert (await client.post("/api/recording/start", headers=bad)).status_code == 401
        good = {"Authorization": "Bearer s3cret"}
        r = await client.post("/api/recording/start", headers=good)
        assert r.status_code == 200 and r.json()["recording"]
        sid = r.json()["id"]
        assert (await client.post("/api/recording/stop")).status_code == 401
        assert (await client.post("/api/recording/stop?token=s3cret")).status_code == 200
        assert (await client.delete(f"/api/sessions/{sid}")).status_code == 401
        assert (await client.get(f"/api/sessions/{sid}")).status_code == 200
        assert (await client.delete(f"/api/sessions/{sid}", headers=good)).status_code == 200


async def test_start_refused_with_a_clear_error_on_a_full_disk(tmp_path, monkeypatch):
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**9, 10**9 - 10**6, 10**6))
    full = settings(tmp_path, **{"recording.min_free_mb": 100})
    async with in_process(full) as client:
        r = await client.post("/api/recording/start")
        assert r.status_code == 503 and r.json()["error"] == "Unavailable"
        assert "disk full: 1.0 MB free" in r.json()["error_msg"]
        status = (await client.get("/api/recording")).json()
        assert status["recording"] is False and "disk full" in status["last_error"]
        assert (await client.get("/api/sessions")).json() == []


async def test_start_refused_when_the_sessions_dir_is_unusable(tmp_path):
    async with in_process(settings(tmp_path)) as client:
        (tmp_path / "sessions").mkdir()
        (tmp_path / "sessions").chmod(0o500)  # read-only: root ignores modes, so also
        if os.geteuid() == 0:  # make it a file behind the store's back
            (tmp_path / "sessions").chmod(0o700)
            os.rename(tmp_path / "sessions", tmp_path / "elsewhere")
            (tmp_path / "sessions").write_text("not a folder")
        r = await client.post("/api/recording/start")
        assert r.status_code == 503, r.text
        assert "Cannot" in r.json()["error_msg"] and "sessions" in r.json()["error_msg"]


# ------------------------------------------------------------------ analysis errors

PHYSICAL, NOFIX = syn.ANALYSIS_PHYSICAL, syn.ANALYSIS_NOFIX


ANALYSIS_ERRORS = [  # path, query, status, error, words of its message
    (f"/api/sessions/{PHYSICAL}/analysis", {"task": "nope"}, 400, "BadRequest", "Unknown task"),
    (
        f"/api/sessions/{PHYSICAL}/analysis",
        {"task": "hover"},
        422,
        "NoTaskWindow",
        "never reached 4 m",
    ),
    (f"/api/sessions/{NOFIX}/analysis", {"task": "hover"}, 422, "NoGpsFix", "GPS fix"),
    (
        "/api/sessions/20261122T050000Z_sim/analysis",
        {"task": "hover"},
        404,
        "NotFound",
        "No session",
    ),
    (
        "/api/sessions/..%2F..%2Fetc%2Fpasswd/analysis",
        {"task": "hover"},
        404,
        "HTTPError",
        "Not Found",
    ),
    (
        "/api/sessions/..passwd/analysis",
        {"task": "hover"},
        400,
        "BadRequest",
        "not a session id",
    ),
    (
        f"/api/sessions/{PHYSICAL}/analysis",
        {"task": "hover", "reference": "north"},
        400,
        "BadRequest",
        "LAT,LON",
    ),
    (
        f"/api/sessions/{PHYSICAL}/analysis",
        {"task": "hover", "margin_m": "-1"},
        422,
        "ValidationError",
        "margin_m",
    ),
    (
        f"/api/sessions/{PHYSICAL}/analysis/pie.png",
        {"task": "hover"},
        404,
        "NotFound",
        "No plot",
    ),
    ("/api/analysis", {"task": "hover"}, 400, "BadRequest", "at least one session"),
]


async def test_analysis_errors_have_the_one_shape(tmp_path):
    syn.write_analysis_sessions(tmp_path / "sessions")
    async with in_process(settings(tmp_path)) as client:  # one analysis worker for all
        for path, params, status, error, words in ANALYSIS_ERRORS:
            r = await client.get(path, params=params)
            assert r.status_code == status, (path, params, r.text)
            body = r.json()
            assert body["error"] == error and words in body["error_msg"], (path, params, body)


# ------------------------------------------------------------------ the request guard


async def test_a_cross_site_page_cannot_change_anything(tmp_path):
    allowed = {"server.allowed_origins": ["http://laptop.field:9000"]}
    async with in_process(settings(tmp_path, **allowed)) as client:
        start = "/api/recording/start"
        # A simple (no preflight) cross-site POST as text/plain.
        evil = {"Origin": "http://evil.example", "Content-Type": "text/plain"}
        r = await client.post(start, headers=evil, content=b"{}")
        assert r.status_code == 403 and r.json()["error"] == "Forbidden"
        assert "evil.example" in r.json()["error_msg"]
        for origin in ("null", "http://127.0.0.1.evil.example", "file://"):
            assert (await client.post(start, headers={"Origin": origin})).status_code == 403
        assert (await client.get("/api/recording")).json()["recording"] is False
        # Reading stays open to any page (the pilot's tools), changing does not.
        assert (await client.get("/api/status", headers=evil)).status_code == 200
        # The station's own page, and an allowed origin, may.
        own = {"Origin": IN_PROCESS_BASE}
        assert (await client.post(start, headers=own)).status_code == 200
        assert (await client.post("/api/recording/stop")).status_code == 200  # no Origin: curl
        laptop = {"Origin": "http://laptop.field:9000"}
        assert (await client.post("/api/recording/stop", headers=laptop)).status_code == 200


async def test_state_changing_bodies_must_be_json_and_not_huge(tmp_path):
    async with in_process(settings(tmp_path)) as client:
        text = {"Content-Type": "text/plain"}
        r = await client.put("/api/replay3d", content=b"session=x", headers=text)
        assert r.status_code == 415 and r.json()["error"] == "UnsupportedMediaType"
        assert (await client.post("/api/task", data={"task_id": "1"})).status_code == 415
        huge = {"Content-Type": "application/json", "Content-Length": "300000000"}
        r = await client.put("/api/replay3d", headers=huge, content=b"{}")
        assert r.status_code == 413 and r.json()["error"] == "PayloadTooLarge"


@pytest.mark.parametrize("n", [300, 5000])
async def test_long_names_are_a_client_error(tmp_path, n):
    async with in_process(settings(tmp_path)) as client:
        sid = await record_session(client, rows=1)
        for path in (
            f"/api/sessions/{'a' * n}",
            f"/api/sessions/{'a' * n}/download",
            f"/api/sessions/{sid}/files/{'b' * n}",
            f"/api/sessions/{sid}/files/front/{'c' * n}.jpg",
            f"/api/sessions/{sid}/files/{'d/' * (n // 2)}x",
        ):
            r = await client.get(path)
            assert 400 <= r.status_code < 500, (path[:60], r.status_code)
            assert set(r.json()) == {"error", "error_msg"}


@pytest.mark.parametrize("mode", ["open", "token"])
async def test_a_rebound_name_is_refused_and_no_site_can_frame_the_pages(tmp_path, mode):
    """DNS rebinding: a page on evil.example re-points its name at the station, and its
    requests are then same-origin for the browser, with `Host: evil.example`: refused,
    in `--open` mode as with a token. The station's addresses, localhost and configured
    names pass; every answer forbids framing by another site."""
    token = {"server.token": "s3cret-token"} if mode == "token" else {}
    hosts = {"server.control": mode, "server.allowed_hosts": ["station.field"], **token}
    async with in_process(settings(tmp_path, **hosts)) as client:
        for host in ("evil.example", "evil.example:8000", "127.0.0.1.nip.io", "x:y:z"):
            r = await client.get("/api/status", headers={"Host": host})
            assert r.status_code == 421 and r.json()["error"] == "MisdirectedRequest", host
            assert r.headers["x-frame-options"] == "SAMEORIGIN"
        assert (await client.get("/", headers={"Host": "evil.example"})).status_code == 421
        r = await client.post("/api/recording/start", headers={"Host": "evil.example"})
        assert r.status_code == 421
        assert (await client.get("/api/recording")).json()["recording"] is False
        for host in ("127.0.0.1:8000", "10.0.0.7", "[::1]:8000", "localhost",
                     "station.field:8000", "STATION.FIELD"):  # fmt: skip
            r = await client.get("/api/status", headers={"Host": host})
            assert r.status_code == 200, host
        page = await client.get("/")
        assert page.status_code == 200 and "text/html" in page.headers["content-type"]
        assert page.headers["content-security-policy"] == "frame-ancestors 'self'"
        assert page.headers["x-frame-options"] == "SAMEORIGIN"
        assert (await client.get("/api/health")).headers["x-frame-options"] == "SAMEORIGIN"
