"""The HTTP control API against a real daemon on the simulated head, over loopback.

One daemon (in this process, API on an ephemeral port) serves the module's tests while it
explores and learns, as on a robot; every endpoint is exercised, with malformed bodies,
out-of-range targets, wrong tokens and concurrent clients. Events are read from the SSE
stream from a known sequence number, never waited for with sleeps.
"""
from __future__ import annotations

import concurrent.futures
import contextlib
import http.client
import json
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.parse

import cv2
import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families

from calib_free.map.file import read_map, write_map
from calib_free.map.gaze_map import GazeMap
from calib_free.gaze.target_patch import target_patch_problem
from calib_free.correspondence.disparity import as_grey_float
from headctl.api.server import ApiServer
from headctl.cli.main import main
from headctl.api.client import ApiClient, ApiError
from headctl.config.head import load_config
from headctl.api.compose import serve
from tests.conftest import sim_head_config, wait_until
from headctl.errors import HeadctlError, UnavailableError
from tests.support import SIM_IDEAL, TLS

pytestmark = pytest.mark.timeout(120)

TOKEN = "s3cret-token-for-the-tests"


@pytest.fixture(scope="module")
def head(tmp_path_factory):
    # A look waiting for frames from a stalled camera lasts 10 s (not 2): long enough for a test
    # to catch it running on a loaded machine, however slowly its client starts.
    with serve(sim_head_config(tmp_path_factory.mktemp("api-state"), frame_timeout_s=10.0,
                                max_queued_looks=3)) as daemon:
        yield daemon, ApiClient(daemon.api_url, timeout_s=10.0)


def raw(client, method, path, body: bytes | str | None = None, headers=None):
    """A request as sent by a sloppy client: (status, parsed JSON or bytes, headers)."""
    parts = urllib.parse.urlsplit(client.url)
    conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=10)
    try:
        conn.request(method, path, body=body, headers=headers or {"Content-Type": "application/json"})
        response = conn.getresponse()
        payload = response.read()
        kind = response.getheader("Content-Type", "")
        return response.status, (json.loads(payload) if "json" in kind else payload), dict(response.getheaders())
    finally:
        conn.close()


def events_after(client, seq, predicate, timeout_s=30.0):
    """Events after `seq` from the SSE stream until `predicate(events)` holds; fails at the deadline."""
    seen: list[dict] = []
    deadline = time.monotonic() + timeout_s
    for event in client.events(after=seq, timeout_s=timeout_s):
        seen.append(event)
        if predicate(seen):
            return seen
        assert time.monotonic() < deadline, f"timed out; events seen: {[e['type'] for e in seen]}"
    raise AssertionError(f"the stream ended; events seen: {[e['type'] for e in seen]}")


def wait_state(client, predicate, timeout_s=20.0, what="state"):
    deadline = time.monotonic() + timeout_s
    while True:
        state = client.state()
        if predicate(state):
            return state
        assert time.monotonic() < deadline, f"timed out waiting for {what}; last state {state}"
        time.sleep(0.05)


# --- state -------------------------------------------------------------------------------------
def test_state_reports_joints_pose_and_learning(head):
    daemon, client = head
    s = wait_state(client, lambda s: s["fixation"]["done"] >= 1, what="a first fixation")
    assert s["state"] == "running" and s["api"] == client.url
    assert set(s["joints"]) == {"pan", "tilt", "left_eye", "right_eye"}
    j, pose = s["joints"], s["pose"]
    # The pose is the joints' as the fixation strategy sees them: vergence = left - right eye.
    assert pose["pan"] == pytest.approx(j["pan"]["position_deg"], abs=1e-3)
    assert pose["vergence"] == pytest.approx(j["left_eye"]["position_deg"] - j["right_eye"]["position_deg"], abs=1e-3)
    assert s["image_size"] == [320, 240] and s["torque"] is True
    assert s["servo_loop"]["rate_hz"] == 100.0
    # The stereo pairs' skew: the packaged cameras are on one grid, so the pairs' stamps agree.
    assert s["stereo"]["pairs"] >= 1 and s["stereo"]["max_abs_s"] <= 0.005
    assert s["world"]["kind"] == "ideal" and s["world"]["parts"]["servos"] == "ideal"  # configs/sim-ideal.yaml


def test_state_answers_while_the_map_is_busy(head):
    """The state is read on the API's event loop: it must not wait for the map's lock, which an
    adaptation (or numba compiling on the first one) can hold for seconds."""
    daemon, client = head
    held, release = threading.Event(), threading.Event()

    def hold(_map):
        held.set()
        release.wait(30)

    holder = threading.Thread(target=daemon.parts.running.adapter.with_map, args=(hold,), name="holds-the-map")
    holder.start()
    try:
        assert held.wait(10), "could not take the map's lock"
        quick = ApiClient(client.url, timeout_s=3.0)
        first = quick.state()
        # Until the answer is built anew with the lock held (the state is cached for 0.1 s).
        rebuilt = wait_state(quick, lambda s: s["uptime_s"] > first["uptime_s"], 5.0, "a state built anew")
        assert not release.is_set() and rebuilt["learning"]["adaptations"] >= first["learning"]["adaptations"]
    finally:
        release.set()
        holder.join(10)


def test_learning_points_come_in_order_and_only_once(head):
    _, client = head
    first = wait_state(client, lambda s: s["learning"]["adaptations_this_run"] >= 2, 60, "two adaptations")
    assert first
    page = client.learning(0)
    points = page["points"]
    assert len(points) >= 2 and page["next"] == points[-1]["n"]
    assert [p["n"] for p in points] == sorted({p["n"] for p in points})
    assert all(0 <= p["retinal_error"] and len(p["output_error_deg"]) == 3 and 0 < p["confidence"] <= 1
               for p in points)
    later = client.learning(page["next"])
    assert all(p["n"] > page["next"] for p in later["points"])


# --- looks -------------------------------------------------------------------------------------
def test_a_target_look_fixates_and_its_events_tell_the_story(head):
    daemon, client = head
    seq = client.state()["events_seq"]
    pose = client.state()["pose"]
    job = client.look_target(160, 120, -5, wait_s=30)
    request = job["request"]
    assert job["state"] in ("done", "failed") and (request["x"], request["y"], request["d"]) == (160, 120, -5)
    # The view the target was chosen in: the pose when it was sent (exploration may move the head meanwhile).
    assert len(request["reference_pose"]) == 3
    assert job["result"]["pose_before"] is not None and job["finished"] >= job["started"] >= job["created"]
    if job["state"] == "done" and job["result"]["head_moved_deg"] <= 0.25:
        # Converged in the view it was chosen in: how near the target it landed is measured.
        assert job["result"]["converged"] and job["result"]["landing_error_px"] >= 0
    assert pose
    events = events_after(client, seq, lambda es: any(e["type"] == "look_done" and e["id"] == job["id"] for e in es))
    mine = [e for e in events if e["type"] in ("look_started", "look_done") and e.get("id") == job["id"]]
    assert [e["type"] for e in mine] == ["look_started", "look_done"]
    between = events[events.index(mine[0]):events.index(mine[1])]
    kinds = [e["type"] for e in between]
    assert "saccade_onset" in kinds and ("fixation_converged" in kinds or "fixation_refused" in kinds)
    assert kinds.index("saccade_onset") < kinds.index("saccade_done")
    assert all(b["seq"] > a["seq"] for a, b in zip(events, events[1:]))


def test_a_queued_target_goes_where_it_was_meant_though_the_head_moved_first(head):
    daemon, client = head
    client.set_exploration(False)
    try:
        wait_state(client, lambda s: s["fixation"]["state"] == "idle (exploration off)")
        move = client.look_angles(0.0, 0.0, 6.0, wait_s=30)
        assert move["state"] == "done", move
        rest = np.asarray(move["result"]["pose_after"])
        move = client.look_angles(15.0, 10.0, 6.0)  # queued first: the head will have moved
        target = client.look_target(200, 90, -4)
        # The view the target was chosen in: the pose when it was sent, at the rest or (the
        # move may have begun by then) on the way from it to the move's goal.
        reference = np.asarray(target["request"]["reference_pose"])
        assert np.all(reference[:2] >= rest[:2] - 0.35) and np.all(reference[:2] <= np.array([15.0, 10.0]) + 0.35)
        assert reference[2] == pytest.approx(rest[2], abs=0.35)
        assert client.look(move["id"], wait_s=30)["state"] == "done"
        job = client.look(target["id"], wait_s=30)
        result = job["result"]
        # The head had moved away: the look first went back to the view the target was chosen in.
        assert result["head_moved_deg"] > 5
        assert result["pose_before"] == pytest.approx(reference.tolist(), abs=0.35)
        # The saccade went to the reference pose plus the map's command for the target (the map
        # as it was then: unchanged unless this look taught it).
        if not result["taught"]:
            daemon.parts.running.adapter.wait_idle(5)
            meant = np.asarray(target["request"]["reference_pose"]) + daemon.parts.running.adapter.command(
                (200, 90, -4), pose=target["request"]["reference_pose"])
            assert np.asarray(result["pose_before"]) + result["planned"] == pytest.approx(meant, abs=0.05)
    finally:
        client.set_exploration(True)


def test_an_angles_look_reaches_the_pose_absolute_and_relative(head):
    _, client = head
    job = client.look_angles(12.0, -6.0, 8.0, wait_s=30)
    assert job["state"] == "done", job
    assert job["result"]["pose_after"] == pytest.approx([12.0, -6.0, 8.0], abs=0.35)
    job = client.look_angles(-2.0, 1.0, 0.0, relative=True, wait_s=30)
    assert job["state"] == "done", job
    before = np.array(job["result"]["pose_before"])
    assert job["result"]["pose_after"] == pytest.approx((before + [-2.0, 1.0, 0.0]).tolist(), abs=0.35)


def test_a_look_without_waiting_gives_an_id_to_wait_on(head):
    _, client = head
    job = client.look_angles(0.0, 0.0, 6.0)
    assert job["state"] in ("queued", "running", "done") and isinstance(job["id"], int)
    finished = client.look(job["id"], wait_s=30)
    assert finished["id"] == job["id"] and finished["state"] == "done"
    assert finished["result"]["pose_after"] == pytest.approx([0.0, 0.0, 6.0], abs=0.35)


@pytest.mark.parametrize("body, field, words", [
    ({"x": 400, "y": 100, "d": 0}, "x", "outside the image's columns, [0, 319]"),
    ({"x": 100, "y": -1, "d": 0}, "y", "outside the image's rows"),
    ({"x": 100, "y": 100, "d": 90}, "d", "disparity range"),
    ({"x": 100, "y": 100, "d": "near"}, "d", "valid number"),
    ({"y": 100, "d": 0}, "x", "Field required"),
    ({"x": "left", "y": 100, "d": 0}, "x", "valid number"),
    ({"x": 100, "y": 100, "d": 0, "speed": 3}, "speed", "Extra inputs are not permitted"),
    ({"x": 100, "y": 100, "d": 0, "wait_s": 600}, "wait_s", "less than or equal to 60"),
])
def test_a_bad_target_is_refused_with_the_field_and_the_reason(head, body, field, words):
    _, client = head
    status, answer, _ = raw(client, "POST", "/api/v1/look/target", json.dumps(body))
    assert status == 422
    assert answer["field"] == field and words in answer["reason"] and answer["error"] == "Unprocessable Entity"


@pytest.mark.parametrize("body, field, words", [
    ({"pan": 55, "tilt": 0, "vergence": 5}, "pan", "outside the limits [-40, 40]"),
    ({"pan": 0, "tilt": 0, "vergence": 40}, "vergence", "outside the limits [1, 20]"),
    ({"pan": 0, "tilt": 0}, None, "vergence missing"),
    ({"tilt": 100, "relative": True}, "tilt", "outside the limits [-25, 25]"),
    ({"pan": float("inf"), "tilt": 0, "vergence": 5}, None, ""),
])
def test_angles_outside_the_limits_are_refused_never_clamped(head, body, field, words):
    _, client = head
    status, answer, _ = raw(client, "POST", "/api/v1/look/angles", json.dumps(body))
    assert status == 422, answer
    assert answer["field"] == field or field is None
    assert words in answer["reason"]
    assert "Traceback" not in json.dumps(answer)
    assert client.state()["fixation"]["looks_queued"] == 0  # nothing was queued


def test_the_openapi_schema_names_every_route_and_the_error_shape(head):
    _, client = head
    status, spec, _ = raw(client, "GET", "/openapi.json")
    assert status == 200
    assert {"/api/v1/state", "/api/v1/look/target", "/api/v1/look/angles", "/api/v1/looks/{look_id}",
            "/api/v1/events", "/api/v1/exploration", "/api/v1/torque", "/api/v1/map/save"} <= set(spec["paths"])
    refusal = spec["paths"]["/api/v1/look/target"]["post"]["responses"]["422"]
    assert refusal["content"]["application/json"]["schema"]["$ref"].endswith("/ErrorBody")
    assert set(spec["components"]["schemas"]["ErrorBody"]["properties"]) == {"error", "field", "reason"}


def test_malformed_bodies_are_4xx_json_never_a_traceback(head):
    _, client = head
    for body in (b"{not json", b"", b"[1, 2, 3]", "{\"x\": 1e999999}".encode(), b"\xff\xfe"):
        status, answer, _ = raw(client, "POST", "/api/v1/look/target", body)
        assert status == 422, (body, answer)
        assert answer["field"] and answer["reason"] and "Traceback" not in json.dumps(answer)
    status, answer, _ = raw(client, "GET", "/api/v1/nowhere")
    assert status == 404 and answer["error"] == "Not Found"
    status, answer, _ = raw(client, "DELETE", "/api/v1/state")
    assert status == 405 and answer["reason"]


# --- a hostile client ----------------------------------------------------------------------------
@pytest.mark.parametrize("path, body, field", [
    ("/api/v1/exploration", {"enabled": 0}, "enabled"),
    ("/api/v1/exploration", {"enabled": "yes"}, "enabled"),
    ("/api/v1/torque", {"enabled": 1}, "enabled"),
    ("/api/v1/look/target", {"x": True, "y": 100, "d": 0}, "x"),
    ("/api/v1/look/target", {"x": 100, "y": "100", "d": 0}, "y"),
    ("/api/v1/look/target", {"x": 100, "y": 100, "d": 0, "replace": 1}, "replace"),
    ("/api/v1/look/target", {"x": 100, "y": 100, "d": 0, "wait_s": False}, "wait_s"),
    ("/api/v1/look/angles", {"pan": 0, "tilt": 0, "vergence": 5, "relative": "false"}, "relative"),
    ("/api/v1/map/reset", {"seed": False}, "seed"),
    ("/api/v1/map/reset", {"seed": 1.5}, "seed"),
    ("/api/v1/map/save", {"name": True}, "name"),
    ("/api/v1/sim/faults", {"fault": "hardware_error", "joint": "pan", "bits": False}, "bits"),
])
def test_loose_types_are_refused_naming_the_field(head, path, body, field):
    """Strict bodies: a bool is not a number, a number or a string is not a bool; nothing is
    done with a refused body (no map reset, no torque off, no look queued)."""
    daemon, client = head
    adaptations = client.state()["learning"]["adaptations"]
    status, answer, _ = raw(client, "POST", path, json.dumps(body))
    assert status == 422 and answer["field"] == field, answer
    assert answer["error"] == "Unprocessable Entity" and answer["reason"].startswith("Input should be")
    state = client.state()
    assert state["torque"] is True and state["fixation"]["looks_queued"] == 0
    assert state["learning"]["adaptations"] >= adaptations  # not reset


@pytest.mark.parametrize("body, words", [(b"\x9dJ7\xba", "'utf-8' codec can't decode"),
                                         (b'{"seed": ' + b"9" * 5000 + b"}", "integer string conversion"),
                                         (b"[" * 20000 + b"]" * 20000, "maximum recursion depth")])
def test_a_body_json_cannot_read_is_400_naming_the_body(head, body, words):
    daemon, client = head
    adaptations = client.state()["learning"]["adaptations"]
    status, answer, _ = raw(client, "POST", "/api/v1/map/reset", body)
    assert status == 400 and answer["field"] == "body" and words in answer["reason"], answer
    assert client.state()["learning"]["adaptations"] >= adaptations  # not reset


def test_an_int_is_still_a_number(head):
    _, client = head
    status, answer, _ = raw(client, "POST", "/api/v1/look/angles",
                            json.dumps({"pan": 2, "tilt": -1, "vergence": 6, "wait_s": 30}))
    assert status == 200 and answer["state"] == "done" and answer["request"]["pan"] == 2.0, answer


@pytest.mark.parametrize("body, field", [({"fault": "hardware_error"}, "joint"),
                                         ({"fault": "hardware_error", "joint": "elbow"}, "joint"),
                                         ({"fault": "camera_stall"}, "camera"),
                                         ({"fault": "camera_resume", "camera": "middle"}, "camera")])
def test_a_fault_without_its_joint_or_camera_is_422(head, body, field):
    _, client = head
    status, answer, _ = raw(client, "POST", "/api/v1/sim/faults", json.dumps(body))
    assert status == 422 and answer["field"] == field, answer
    assert client.state()["state"] == "running"


def test_the_openapi_schema_lists_every_answer_and_media_type(head):
    _, client = head
    status, spec, _ = raw(client, "GET", "/openapi.json")
    assert status == 200
    paths = spec["paths"]

    def answers(path, method):
        return paths[path][method]["responses"]

    for path in ("/api/v1/look/target", "/api/v1/look/angles"):
        assert {"200", "202", "400", "408", "413", "422", "429", "431", "503"} <= set(answers(path, "post")), path
    assert {"202", "404", "422"} <= set(answers("/api/v1/looks/{look_id}", "get"))
    assert {"202", "404", "409", "422"} <= set(answers("/api/v1/looks/{look_id}", "delete"))
    for path, ops in paths.items():
        for method, op in ops.items():
            assert {"400", "413", "503"} <= set(op["responses"]), (method, path)
            for code, answer in op["responses"].items():
                if code >= "400":  # every refusal is the JSON error shape, whatever the route serves
                    assert answer["content"] == {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorBody"}}}
            if op.get("requestBody") or op.get("parameters"):
                assert "422" in op["responses"], (method, path)
    assert set(answers("/api/v1/eyes/{side}.jpg", "get")["200"]["content"]) == {"image/jpeg"}
    assert set(answers("/api/v1/eyes/{side}.mjpg", "get")["200"]["content"]) == {"multipart/x-mixed-replace"}
    assert set(answers("/api/v1/events", "get")["200"]["content"]) == {"text/event-stream"}
    assert set(answers("/api/v1/state", "get")["200"]["content"]) == {"application/json"}


def connect(url: str) -> socket.socket:
    parts = urllib.parse.urlsplit(url)
    return socket.create_connection((parts.hostname, parts.port), timeout=10)


def read_to_eof(sock: socket.socket, timeout_s: float) -> tuple[bytes, float]:
    """Everything the server sends until it closes the connection, and when that was
    (time.monotonic()); fails if it is still open after `timeout_s`."""
    data = b""
    deadline = time.monotonic() + timeout_s
    while True:
        sock.settimeout(max(0.01, deadline - time.monotonic()))
        try:
            chunk = sock.recv(65536)
        except TimeoutError:
            raise AssertionError(f"still open after {timeout_s} s; received {data[:200]!r}") from None
        except ConnectionResetError:
            chunk = b""
        if not chunk:
            return data, time.monotonic()
        data += chunk


def answer_of(data: bytes) -> tuple[int, dict[str, str], dict]:
    """The status, headers and JSON body of one HTTP answer."""
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    headers = {k.strip().lower(): v.strip() for k, v in (line.split(":", 1) for line in lines[1:])}
    return int(lines[0].split()[1]), headers, json.loads(body)


def test_a_50_mb_body_is_refused_before_it_is_read(head):
    _, client = head
    post = (b"POST /api/v1/look/target HTTP/1.1\r\nHost: head\r\nContent-Type: application/json\r\n"
            b"Content-Length: %d\r\n\r\n" % (50 << 20))
    # By its Content-Length: 413 as soon as the head is read, not a byte of the body awaited.
    with connect(client.url) as sock:
        sent = time.monotonic()
        sock.sendall(post)
        data, closed = read_to_eof(sock, 5.0)
    status, headers, answer = answer_of(data)
    assert status == 413 and answer["field"] == "body" and "52428800 bytes" in answer["reason"], answer
    assert headers["connection"] == "close" and closed - sent < 0.5

    # Sent whole by a client that does not wait for an answer: the server stops reading near
    # the cap and closes the connection, so the client cannot push 50 MB.
    with connect(client.url) as sock:
        pushed = 0
        body = b"1" * (1 << 20)
        started = time.monotonic()
        sock.sendall(post)
        try:
            while pushed < 50 << 20:
                pushed += sock.send(body)
        except OSError:  # reset by the server (it closed with the rest unread)
            pass
        elapsed = time.monotonic() - started
    assert pushed < 25 << 20 and elapsed < 2.0, (pushed, elapsed)

    # Chunked (no Content-Length): counted as it arrives, refused once past the cap.
    with connect(client.url) as sock:
        chunk = b"1" * 16384
        sock.sendall(b"POST /api/v1/look/target HTTP/1.1\r\nHost: head\r\nContent-Type: application/json\r\n"
                     b"Transfer-Encoding: chunked\r\n\r\n" + b"4000\r\n" + chunk + b"\r\n")
        for _ in range(4):
            sock.sendall(b"4000\r\n" + chunk + b"\r\n")
        data, _ = read_to_eof(sock, 5.0)
    status, headers, answer = answer_of(data)
    assert status == 413 and answer["field"] == "body" and "over 65536 bytes" in answer["reason"], answer
    assert headers["connection"] == "close"


def test_malformed_http_and_oversized_heads_get_the_error_shape(head):
    _, client = head
    for request, status in ((b"GET /api/v1/state HTTP/1.1\r\nHost: head\r\nContent-Length: x\r\n\r\n", 400),
                            (b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03", 400),  # a TLS hello
                            (b"GET /api/v1/state HTTP/1.1\r\nHost: head\r\nX-Big: " + b"a" * 40000, 431),
                            (b"GET /api/v1/state HTTP/1.1\r\nHost: head\r\nX-Big: " + b"a" * 40000 + b"\r\n\r\n",
                             431)):
        with connect(client.url) as sock:
            sock.sendall(request)
            data, _ = read_to_eof(sock, 5.0)
        code, headers, answer = answer_of(data)
        assert code == status and headers["content-type"] == "application/json", data[:300]
        assert set(answer) == {"error", "field", "reason"} and answer["reason"]
    status, answer, _ = raw(client, "OPTIONS", "/api/v1/state")
    assert status == 405 and answer["error"] == "Method Not Allowed"


@pytest.fixture
def strict_server(head):
    """A second API server over the module's daemon, with short limits to test them."""
    daemon, _ = head
    with ApiServer(daemon.control, port=0, request_timeout_s=0.5, max_connections=4) as server:
        yield server


def test_half_open_connections_are_answered_408_and_closed(strict_server):
    opened = time.monotonic()
    silent, half_line, half_body = (connect(strict_server.url) for _ in range(3))
    half_line.sendall(b"GET /api/v1/sta")
    half_body.sendall(b"POST /api/v1/look/target HTTP/1.1\r\nHost: head\r\nContent-Type: application/json\r\n"
                      b"Content-Length: 40\r\n\r\n{\"x\": 1")
    for sock in (silent, half_line, half_body):
        with sock:
            data, closed = read_to_eof(sock, 5.0)
        status, headers, answer = answer_of(data)
        assert status == 408 and headers["connection"] == "close" and "within 0.5 s" in answer["reason"]
        assert 0.5 <= closed - opened < 3.0
    # A kept-alive connection: answered, then half a request; its time starts at its first byte.
    with connect(strict_server.url) as kept:
        kept.sendall(b"GET /api/v1/state HTTP/1.1\r\nHost: head\r\n\r\n")
        kept.settimeout(5)
        reply = kept.recv(65536)
        assert reply.startswith(b"HTTP/1.1 200")
        started = time.monotonic()
        kept.sendall(b"GET /api/v1/state HTTP/1.1\r\nHo")
        data, closed = read_to_eof(kept, 5.0)
    rest = data[data.index(b"HTTP/1.1 408"):]  # after what remained of the first answer
    assert answer_of(rest)[0] == 408 and 0.5 <= closed - started < 3.0


def test_the_request_timeout_does_not_cut_a_long_answer(strict_server):
    """The timeout covers reading the request; an event stream lasts."""
    with connect(strict_server.url) as sock:
        sock.sendall(b"GET /api/v1/events?after=0 HTTP/1.1\r\nHost: head\r\n\r\n")
        started = time.monotonic()
        received = b""
        while time.monotonic() - started < 1.5:  # three request timeouts
            sock.settimeout(0.1)
            try:
                chunk = sock.recv(65536)
            except TimeoutError:
                continue
            assert chunk, "the server closed the event stream"
            received += chunk
    assert received.startswith(b"HTTP/1.1 200") and b"event: " in received


def test_beyond_the_connection_cap_requests_are_answered_503(strict_server):
    parts = urllib.parse.urlsplit(strict_server.url)
    held = [http.client.HTTPConnection(parts.hostname, parts.port, timeout=5) for _ in range(4)]

    def one_more() -> tuple[int, dict]:
        conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=5)
        try:
            conn.request("GET", "/api/v1/state")
            response = conn.getresponse()
            return response.status, json.loads(response.read())
        finally:
            conn.close()

    try:
        for conn in held:  # four connections open (kept alive once answered): the cap
            conn.request("GET", "/api/v1/state")
            response = conn.getresponse()
            assert response.status == 200
            response.read()
        status, answer = one_more()
        assert status == 503 and answer["field"] is None and "over 4 connections" in answer["reason"], answer
        held.pop().close()
        wait_until(lambda: one_more()[0] == 200, 5.0, "a connection served once one closed")
    finally:
        for conn in held:
            conn.close()


def test_unknown_looks_and_cancelling(head):
    daemon, client = head
    with pytest.raises(ApiError) as err:
        client.look(987654)
    assert err.value.status == 404 and err.value.field == "id"
    client.set_exploration(False)
    try:
        first = client.look_angles(5.0, 0.0, 6.0)
        queued = [client.look_angles(a, 0.0, 6.0) for a in (-5.0, 5.0)]
        # Queued (or, if the fixation thread took it meanwhile, running) ones can be cancelled.
        status, answer, _ = raw(client, "DELETE", f"/api/v1/looks/{queued[-1]['id']}?wait_s=10")
        if status == 200:
            assert answer["state"] == "cancelled" and answer["outcome"] == "cancelled"
        else:  # it had ended already (a very slow host)
            assert status == 409 and "done already" in answer["reason"]
        done = client.look(first["id"], wait_s=30)
        assert done["state"] == "done"
        # A finished one cannot.
        status, answer, _ = raw(client, "DELETE", f"/api/v1/looks/{first['id']}")
        assert status == 409 and answer["field"] == "id" and "done already" in answer["reason"]
        client.look(queued[0]["id"], wait_s=30)
    finally:
        client.set_exploration(True)


@contextlib.contextmanager
def idle_with_the_left_camera_stalled(client):
    """Exploration off and the head idle at the centre of its range, the left camera stalled:
    a target look then waits for frames (up to the module daemon's 10 s frame timeout) and can
    be caught running. At the centre, whatever the module's earlier tests (or another worker's
    share of them) left, the target is within reach and is not refused before it runs."""
    client.set_exploration(False)
    wait_state(client, lambda s: s["fixation"]["state"] == "idle (exploration off)", what="idle")
    assert client.look_angles(0.0, 0.0, 6.0, wait_s=10)["state"] == "done"
    client.request("POST", "/api/v1/sim/faults", {"fault": "camera_stall", "camera": "left"})
    try:
        yield
    finally:
        client.request("POST", "/api/v1/sim/faults", {"fault": "camera_resume", "camera": "left"})
        client.set_exploration(True)


def test_a_running_look_stops_when_cancelled_or_replaced(head):
    """A look waiting for frames (the left camera stalled) is stopped at once, well before the
    fixation's 10 s frame timeout: by DELETE, then by a newer look with replace."""
    daemon, client = head
    with idle_with_the_left_camera_stalled(client):
        seq = client.state()["events_seq"]
        job = client.look_target(160.0, 120.0, 0.0)
        events_after(client, seq, lambda es: any(e["type"] == "look_started" and e["id"] == job["id"] for e in es))
        asked_s = time.time()
        stopped = client.cancel_look(job["id"], wait_s=10)
        assert stopped["state"] == "cancelled" and stopped["outcome"] == "cancelled", stopped
        assert stopped["cancel_requested"] is True and stopped["finished"] - asked_s < 1.0
        assert stopped["result"]["taught"] == 0  # fixations that taught: none

        seq = client.state()["events_seq"]
        older = client.look_target(100.0, 100.0, 0.0)
        events_after(client, seq, lambda es: any(e["type"] == "look_started" and e["id"] == older["id"] for e in es))
        newer = client.look_angles(0.0, 0.0, 6.0, replace=True)
        replaced = client.look(older["id"], wait_s=10)
        assert replaced["state"] == "cancelled" and replaced["outcome"] == "replaced", replaced
        assert replaced["detail"] == "a newer look replaced it"
        client.request("POST", "/api/v1/sim/faults", {"fault": "camera_resume", "camera": "left"})
        assert client.look(newer["id"], wait_s=30)["state"] == "done"
        refused = client.state()["fixation"]["refused"]
        assert refused.get("look cancelled", 0) >= 2  # stopped fixations are counted, never taught


def look_without_d(client, x, y, **kw):
    """A look at (x, y) without d; asked again while the daemon has no pair recent enough (503:
    on a loaded machine the cameras' threads can fall more than 0.5 s behind for a moment)."""
    def post():
        try:
            return client.look_target(x, y, **kw)
        except ApiError as err:
            if err.status == 503 and "no stereo pair" in err.reason:
                return None
            raise
    return wait_until(post, timeout_s=10.0, what=f"a stereo pair recent enough to look at ({x}, {y}) in")


def measured_or_none(control, x, y):
    """The service's disparity at (x, y) of the latest pair; None while it has no recent pair."""
    try:
        return control.measure_disparity(x, y)
    except UnavailableError:
        return None


def test_a_target_without_d_has_its_disparity_measured_there(head):
    daemon, client = head
    client.set_exploration(False)
    try:
        wait_state(client, lambda s: s["fixation"]["state"] == "idle (exploration off)", what="idle")
        converged = None
        look_params = daemon.parts.running.fixation.controller.params.look
        w, h = daemon.config.image_size
        for x, y in ((100, 80), (220, 160), (60, 200), (280, 40), (120, 180), (160, 60), (200, 200), (80, 140)):
            try:
                job = look_without_d(client, float(x), float(y), wait_s=30)
            except ApiError as err:  # no patch to find the target by in this view
                assert err.status == 422 and err.field == "d" and "cannot be looked at" in err.reason
                continue
            request = job["request"]
            if not request["d_measured"]:  # looked at from the fixation's depth; tested below
                continue
            assert request["d_ncc"] >= 0.6 and "d_reason" not in request, request
            low, high = daemon.parts.running.adapter.map.params.disparity_range
            assert low <= request["d"] <= high
            # Fine vergence converged where the look ended, on something a look can find again, and
            # the fixation taught: its stereo match passed the correspondence's checks. (Where the
            # foveae's match is ambiguous along the rows, another pair's noise can flip it to
            # another peak: 2 of 938 converged fixations in the ideal world, both refused.)
            fovea = as_grey_float(daemon.parts.devices.cameras["left"].latest().image)
            last = job["result"]["fixations"][-1] if job["result"]["fixations"] else {}
            if (job["result"]["converged"] and last.get("taught")
                    and not target_patch_problem(fovea, ((w - 1) / 2, (h - 1) / 2), look_params)):
                converged = job
                break
        assert converged is not None, "no look converged and taught in eight"
        # Fine vergence left the fixated point at zero disparity: measured at the fovea now, d ~ 0
        # (the measurement a look without d makes; a look there may be beyond the reach of a map
        # that has learned little).
        at_fovea = wait_until(lambda: measured_or_none(daemon.control, (w - 1) / 2, (h - 1) / 2), timeout_s=10.0,
                              what="a stereo pair recent enough to measure the fovea's disparity in")
        assert at_fovea.ncc is not None and abs(at_fovea.d) <= 1.5, at_fovea
        # Where no patch fits, there is nothing to look at: refused, naming d.
        with pytest.raises(ApiError) as err:
            client.look_target(2.0, 2.0)
        assert err.value.status == 422 and err.value.field == "d" and "beyond the image" in err.value.reason
    finally:
        client.set_exploration(True)


def test_a_target_whose_d_cannot_be_measured_is_looked_at_from_the_fixation_depth(head):
    """12 px from the left edge the 32 x 20 patch that measures d does not fit, the look's
    21 x 21 patch does: the look goes ahead with d 0, says so, and is `done` only on target."""
    daemon, client = head
    client.set_exploration(False)
    try:
        wait_state(client, lambda s: s["fixation"]["state"] == "idle (exploration off)", what="idle")
        look_params = daemon.parts.running.fixation.controller.params.look
        w, h = daemon.config.image_size
        candidates = [(x, float(y)) for y in range(30, h - 30, 20) for x in (12.0, w - 13.0)]
        job = None
        for x, y in candidates:  # the first whose patch identifies it in this view
            frame = daemon.parts.devices.cameras["left"].latest()
            if target_patch_problem(as_grey_float(frame.image), (x, y), look_params):
                continue
            try:
                job = look_without_d(client, x, y, wait_s=30)
            except ApiError as err:  # the view changed since the frame was read, or the map sends it beyond the limits
                assert err.status == 422 and (err.field == "d" and "cannot be looked at" in err.reason
                                              or err.field == "x" and "beyond the joint limits" in err.reason)
                continue
            break
        assert job is not None, "no target near the border with a patch to find it by"
        request, result = job["request"], job["result"]
        assert request["d_measured"] is False and request["d"] == 0.0 and "d_ncc" not in request, request
        assert "could not be measured" in request["d_reason"] and "d = 0" in request["d_reason"], request
        assert job["state"] in ("done", "failed"), job
        on_target = result["final_error_px"] is not None and result["final_error_px"] <= result["tolerance_px"]
        assert (job["state"] == "done") == (result["on_target"] and on_target), job
    finally:
        client.set_exploration(True)


def test_without_a_recent_stereo_pair_d_cannot_be_measured(head):
    daemon, client = head
    with idle_with_the_left_camera_stalled(client):
        deadline = time.monotonic() + 10
        while True:  # until the last pair is older than the daemon accepts (0.5 s)
            try:
                client.look_target(160.0, 120.0, replace=True)
            except ApiError as err:
                if err.status != 422:  # 422: nothing to match at the fovea in the last pair; ask again
                    refused = err
                    break
            assert time.monotonic() < deadline, "a disparity was still measured 10 s after the camera stalled"
            time.sleep(0.05)
        assert refused.status == 503 and refused.field == "d" and "no stereo pair from the last" in refused.reason
        sent = client.look_target(160.0, 120.0, 0.0, replace=True)["request"]
        assert sent["d_measured"] is False and "d_reason" not in sent, sent  # the client's own d


def test_a_full_queue_is_429_and_replace_makes_the_newest_win(head):
    daemon, client = head
    client.set_exploration(False)
    assert daemon.parts.looks.size == 3  # the config's api.max_queued_looks
    try:
        # Fill faster than the head moves: 1 running + 3 queued; then one more is refused.
        jobs, refused = [], None
        for i in range(8):
            try:
                jobs.append(client.look_angles(-10.0 + 3 * i, 0.0, 6.0))
            except ApiError as err:
                refused = err
                break
        assert refused is not None and refused.status == 429 and "already queued" in refused.reason
        newest = client.look_angles(1.0, 2.0, 7.0, replace=True)
        outcomes = [client.look(j["id"], wait_s=30) for j in jobs]
        assert any(o["state"] == "cancelled" and o["outcome"] == "replaced" for o in outcomes)
        assert client.look(newest["id"], wait_s=30)["state"] == "done"
    finally:
        client.set_exploration(True)


# --- switches ------------------------------------------------------------------------------------
def test_exploration_off_stops_fixations_and_on_resumes_them(head):
    daemon, client = head
    seq = client.state()["events_seq"]
    assert client.set_exploration(False) is False
    s = wait_state(client, lambda s: s["fixation"]["state"] == "idle (exploration off)", what="idle")
    assert s["fixation"]["explore"] is False
    done = s["fixation"]["done"]
    events = events_after(client, seq, lambda es: any(e["type"] == "exploration" for e in es))
    assert [e["enabled"] for e in events if e["type"] == "exploration"] == [False]
    # No fixation starts while it is off: the count holds across several servo-loop seconds.
    cycles = s["servo_loop"]["cycles"]
    wait_state(client, lambda s: s["servo_loop"]["cycles"] >= cycles + 150, what="1.5 s of servo cycles")
    assert client.state()["fixation"]["done"] == done
    assert client.set_exploration(True) is True
    wait_state(client, lambda s: s["fixation"]["done"] > done, 30, "fixations again")


def test_torque_off_holds_nothing_refuses_looks_and_comes_back_without_a_jump(head):
    daemon, client = head
    client.set_exploration(False)
    try:
        wait_state(client, lambda s: s["fixation"]["state"] == "idle (exploration off)")
        assert client.set_torque(False) is False
        s = client.state()
        assert s["torque"] is False and not any(j["torque_on"] for j in s["joints"].values())
        job = client.look_angles(3.0, 3.0, 6.0, wait_s=10)
        assert job["state"] == "failed" and job["outcome"] == "torque off"
        positions = {k: j["position_deg"] for k, j in s["joints"].items()}
        assert client.set_torque(True) is True
        s = wait_state(client, lambda s: all(j["torque_on"] for j in s["joints"].values()), what="torque on")
        # Torque came back at the present position (the goal set there first): nothing moved.
        for joint, position in positions.items():
            assert s["joints"][joint]["position_deg"] == pytest.approx(position, abs=0.2)
        assert client.look_angles(3.0, 3.0, 6.0, wait_s=30)["state"] == "done"
    finally:
        client.set_torque(True)
        client.set_exploration(True)


# --- the map -----------------------------------------------------------------------------------
def test_map_save_load_reset_and_their_refusals(head):
    daemon, client = head
    state_dir = daemon.config.state_dir
    wait_state(client, lambda s: s["learning"]["adaptations"] >= 1, 60, "an adaptation")
    saved = client.request("POST", "/api/v1/map/save", {"name": "snapshot.npz"})
    assert saved["path"] == str(state_dir / "snapshot.npz") and read_map(saved["path"]).adaptations >= 1
    default = client.request("POST", "/api/v1/map/save", {})
    assert default["path"] == str(state_dir / "gaze_map.npz")

    reset = client.request("POST", "/api/v1/map/reset", {"seed": 7})
    assert reset["adaptations"] == 0 and read_map(reset["backup"]).adaptations >= saved["adaptations"]
    assert client.state()["learning"]["adaptations"] < saved["adaptations"] or saved["adaptations"] < 3
    loaded = client.request("POST", "/api/v1/map/load", {"name": "snapshot.npz"})
    assert loaded["adaptations"] == saved["adaptations"]
    assert client.state()["learning"]["adaptations"] >= saved["adaptations"]

    for body, status, field, words in (
            ({"name": "../etc/passwd"}, 422, "name", "a file name in the state directory"),
            ({"name": "missing.npz"}, 404, "name", "no such map file"),
            ({"name": 5}, 422, "name", "valid string")):
        code, answer, _ = raw(client, "POST", "/api/v1/map/load", json.dumps(body))
        assert code == status and answer["field"] == field and words in answer["reason"], answer
    # A map made for another image size is refused, the running one kept.
    other = GazeMap(load_config(SIM_IDEAL).map_params().__class__.profile_values("default", image_size=(640, 480)))
    write_map(other, state_dir / "other.npz")
    code, answer, _ = raw(client, "POST", "/api/v1/map/load", json.dumps({"name": "other.npz"}))
    assert code == 409 and "other map parameters" in answer["reason"]


# --- streams and metrics -----------------------------------------------------------------------
def test_eye_images_have_the_fovea_marked(head):
    daemon, client = head
    for side in ("left", "right"):
        status, payload, headers = raw(client, "GET", f"/api/v1/eyes/{side}.jpg")
        assert status == 200 and headers["content-type"] == "image/jpeg"
        image = cv2.imdecode(np.frombuffer(payload, np.uint8), cv2.IMREAD_COLOR)
        assert image.shape == (240, 320, 3)
        # The cross's four arms (cx, cy = 160, 120; arms 8 px): green. The last match's yellow
        # circle may cover one of them, never most.
        arms = [image[119:122, 150:156], image[119:122, 164:170], image[110:116, 159:162], image[124:130, 159:162]]
        green = [(lambda b, g, r: g > 150 and g > max(r, b) + 50)(*arm.astype(int).mean(axis=(0, 1))) for arm in arms]
        assert sum(green) >= 3, green
        # The scene elsewhere: grey. The overlays are thin lines, which may cross any one spot
        # (the last match's circle lies wherever the match was): most pixels are grey.
        b, g, r = (image[..., k].astype(int) for k in range(3))
        assert np.median(np.abs(g - r)) < 20 and np.median(np.abs(g - b)) < 20
    status, answer, _ = raw(client, "GET", "/api/v1/eyes/middle.jpg")
    assert status == 422 and answer["field"] == "side"


def test_the_mjpeg_stream_sends_successive_frames(head):
    _, client = head
    parts = urllib.parse.urlsplit(client.url)
    conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=10)
    conn.request("GET", "/api/v1/eyes/left.mjpg?fps=20")
    response = conn.getresponse()
    assert response.status == 200 and "boundary=frame" in response.getheader("Content-Type")
    frames = []
    while len(frames) < 3:
        line = response.readline()
        if line.lower().startswith(b"content-length:"):
            length = int(line.split(b":")[1])
            response.readline()
            frames.append(response.read(length))
    conn.close()
    images = [cv2.imdecode(np.frombuffer(f, np.uint8), cv2.IMREAD_GRAYSCALE) for f in frames]
    assert all(im.shape == (240, 320) for im in images)
    assert not np.array_equal(images[0], images[-1])  # live: sensor noise at least


def test_metrics_expose_the_loop_fixations_learning_and_servos(head):
    _, client = head
    wait_state(client, lambda s: s["fixation"]["taught"] >= 1, 60, "a taught fixation")
    state = client.state()
    status, payload, headers = raw(client, "GET", "/metrics")
    assert status == 200 and headers["content-type"].startswith("text/plain")
    samples = [s for f in text_string_to_metric_families(payload.decode()) for s in f.samples]

    def value(name, **labels):
        return next(s.value for s in samples if s.name == name and all(s.labels.get(k) == v for k, v in labels.items()))

    def labels(name, key):
        return {s.labels[key] for s in samples if s.name == name}

    assert value("headctl_up") == 1.0
    assert value("headctl_fixations_total") >= state["fixation"]["done"]
    assert value("headctl_fixations_taught_total") >= state["fixation"]["taught"] >= 1
    assert value("headctl_servo_loop_cycles_total") >= state["servo_loop"]["cycles"]
    assert 0.009 < value("headctl_servo_loop_period_seconds", quantile="0.5") < 0.011
    assert value("headctl_servo_temperature_celsius", joint="tilt") > 0
    assert value("headctl_servo_input_voltage_volts", joint="pan") > 5
    assert 0 < value("headctl_retinal_error_ratio") < 2 and 0 < value("headctl_confidence_ratio") <= 1
    assert labels("headctl_output_error_degrees", "axis") == {"pan", "tilt", "vergence"}
    assert labels("headctl_servo_bus_errors_total", "kind") == {"read", "write", "down"}
    for reason, count in state["fixation"]["refused"].items():
        assert value("headctl_fixations_refused_total", reason=reason) >= count


def test_a_fault_and_its_clearing_are_events_and_state(head):
    daemon, client = head
    seq = client.state()["events_seq"]
    client.request("POST", "/api/v1/sim/faults", {"fault": "bus_down"})
    try:
        s = wait_state(client, lambda s: s["state"] == "degraded", what="degraded")
        assert any("servo bus down" in f for f in s["faults"])
    finally:
        # At once: a fault shorter than the supervisor's poll is reported all the same.
        client.request("POST", "/api/v1/sim/faults", {"fault": "restore_bus"})
    events = events_after(client, seq, lambda es: any(e["type"] == "fault_cleared" for e in es))
    fault = next(e for e in events if e["type"] == "fault")
    cleared = next(e for e in events if e["type"] == "fault_cleared")
    assert fault["key"] == cleared["key"] == "servo_bus" and "servo bus down" in fault["message"]
    wait_state(client, lambda s: s["state"] == "running", what="running again")
    code, answer, _ = raw(client, "POST", "/api/v1/sim/faults", json.dumps({"fault": "meteor"}))
    assert code == 422 and answer["field"] == "fault"


def test_an_overload_rebooted_at_once_is_still_a_fault_an_event_and_a_count(head):
    """The bus reboots a servo whose overload cut its torque inside one read: the state never
    reads the error, and the episode is told all the same."""
    daemon, client = head
    seq = client.state()["events_seq"]
    client.request("POST", "/api/v1/sim/faults", {"fault": "hardware_error", "joint": "tilt", "bits": 0x20})

    def tilt(es, kind):
        return [e for e in es if e["type"] == kind and e.get("key", "").startswith("servo:tilt:")]

    events = events_after(client, seq, lambda es: bool(tilt(es, "fault_cleared")))
    fault, cleared = tilt(events, "fault")[0], tilt(events, "fault_cleared")[0]
    assert fault["key"] == cleared["key"] and fault["meanings"] == ["overload"] and fault["servo_id"] == 2
    assert "rebooted" in [e["recovery"] for e in tilt(events, "fault_update")]
    assert cleared["cleared_by"] == "automatic reboot"
    reboots = client.state()["hardware_errors"]["reboots"]
    assert any(r["joint"] == "tilt" and r["reason"] == "overload" and r["count"] >= 1 for r in reboots)
    status, text, _ = raw(client, "GET", "/metrics")
    assert status == 200 and b'headctl_servo_reboots_total{joint="tilt",reason="overload"}' in text


# --- many clients at once -------------------------------------------------------------------------
def test_concurrent_clients_while_the_head_learns(head):
    daemon, client = head
    before = client.state()
    rng = np.random.default_rng(3)

    def one_client(seed: int) -> list[int]:
        own = ApiClient(client.url, timeout_s=30)
        r = np.random.default_rng(seed)
        codes = []
        for i in range(20):
            try:
                kind = i % 4
                if kind == 0:
                    own.look_target(float(r.uniform(40, 280)), float(r.uniform(30, 210)), float(r.uniform(-30, 5)),
                                    replace=True)
                elif kind == 1:
                    own.learning(0)
                else:
                    assert own.state()["state"] in ("running", "degraded")
                codes.append(200)
            except ApiError as err:  # 422 only for a target the young map sends beyond the joint limits
                unreachable = err.status == 422 and err.field == "x" and "beyond the joint limits" in err.reason
                codes.append(200 if unreachable else err.status or 0)
        return codes

    with concurrent.futures.ThreadPoolExecutor(8) as pool:
        results = list(pool.map(one_client, rng.integers(0, 1 << 30, 8)))
    codes = [c for r in results for c in r]
    assert len(codes) == 160 and all(c in (200, 429) for c in codes), sorted(set(codes))
    after = wait_state(client, lambda s: s["fixation"]["done"] > before["fixation"]["done"], 30, "fixations")
    # The servo loop ran at its rate throughout (cycles ~ 100 per second).
    assert after["servo_loop"]["cycles"] > before["servo_loop"]["cycles"]
    assert after["state"] == "running" and not daemon.front_end.error


# --- the command line as a client --------------------------------------------------------------
def test_look_and_status_commands(head, capsys):
    daemon, client = head
    url = ["--url", client.url]
    assert main(["look", "--angles", "4", "-3", "7", *url]) == 0
    out = capsys.readouterr().out
    assert "done, reached" in out and "pose now: pan 4.00, tilt -3.00" in out
    assert main(["look", "--angles", "90", "0", "5", *url]) == 1
    assert "422" in capsys.readouterr().err
    code = main(["look", "150", "110", "-3", *url])
    out = capsys.readouterr().out
    assert code in (0, 1) and out.startswith("look ") and "target x 150, y 110, d -3 px" in out
    if code == 0:  # done: the target ended within the tolerance of the fovea, and the line says how near
        assert "on target: the target ended " in out and "px from the left fovea (tolerance 1 px)" in out
    assert main(["look", "--relative", "1", "2", "3", *url]) == 2
    for values, expected in ((["1", "2", "--angles"], "expected P T V"), (["1"], "expected X Y [D]"),
                             (["1", "2", "3", "4"], "expected X Y [D]")):
        assert main(["look", *values, *url]) == 2
        assert expected in capsys.readouterr().err
    code = main(["look", "100", "80", *url])  # d measured by the daemon, or why it could not be
    out, err = capsys.readouterr()
    if "422" in err:  # nothing there a look could find again
        assert code == 1 and "d: " in err and "cannot be looked at" in err
    else:  # measured, or looked at from the fixation's depth saying why
        assert code in (0, 1) and "target x 100, y 80, d " in out
        assert "(measured, NCC " in out or "(not measured: " in out, out
    assert main(["status", *url]) == 0
    assert "fixation:" in capsys.readouterr().out


def test_ctrl_c_on_headctl_look_cancels_the_look(head):
    daemon, client = head
    with idle_with_the_left_camera_stalled(client):
        cli = subprocess.Popen([sys.executable, "-m", "headctl", "look", "150", "110", "-3", "--url", client.url],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        waiting = cli.stderr.readline()  # the command has the look's id and waits on it
        assert waiting.startswith("look ") and "Ctrl-C cancels it" in waiting, waiting
        look_id = int(waiting.split()[1])
        # Running (waiting for the stalled camera's frames): asked of the look itself, so that
        # Ctrl-C goes as soon as it runs, whatever else the event stream carries.
        deadline = time.monotonic() + 5.0
        while client.look(look_id)["state"] != "running":
            assert time.monotonic() < deadline, client.look(look_id)
            time.sleep(0.02)
        cli.send_signal(signal.SIGINT)
        out, err = cli.communicate(timeout=20)
        assert cli.returncode == 1, (out, err)
        assert f"look {look_id} (target x 150, y 110, d -3 px): cancelled, cancelled" in out
        assert client.look(look_id)["state"] == "cancelled"


# --- a token ---------------------------------------------------------------------------------
def test_a_token_guards_every_route_but_the_page(tmp_path, start_service):
    daemon = start_service(sim_head_config(tmp_path / "state", token=TOKEN))
    anonymous = ApiClient(daemon.api_url)
    for method, path in (("GET", "/api/v1/state"), ("POST", "/api/v1/look/target"), ("GET", "/metrics"),
                         ("GET", "/api/v1/eyes/left.jpg")):
        status, answer, headers = raw(anonymous, method, path, "{}")
        assert status == 401 and "token is required" in answer["reason"], (path, answer)
        assert headers["www-authenticate"].startswith("Bearer")
    with pytest.raises(ApiError) as err:
        ApiClient(daemon.api_url, token="wrong-token-wrong-token").state()
    assert err.value.status == 401 and err.value.reason == "wrong token"
    assert ApiClient(daemon.api_url, token=TOKEN).state()["state"] in ("running", "degraded")
    status, _, _ = raw(anonymous, "GET", f"/api/v1/state?token={TOKEN}")
    assert status == 200
    status, page, _ = raw(anonymous, "GET", "/")
    assert status == 200


def test_the_event_stream_ends_when_the_daemon_stops(tmp_path, start_service):
    daemon = start_service(sim_head_config(tmp_path / "state"))
    client = ApiClient(daemon.api_url)
    ended = threading.Event()

    def read() -> None:
        for _ in client.events(after=0, timeout_s=30):
            pass
        ended.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    wait_state(client, lambda s: daemon.parts.hub.subscribers == 1, what="the stream subscribed")
    started = time.monotonic()
    daemon.stop()
    assert ended.wait(10) and time.monotonic() - started < 10
    assert daemon.parts.hub.subscribers == 0
    assert not (daemon.config.state_dir / "api.url").exists()


def test_a_port_in_use_is_a_clear_error_at_start(tmp_path, capsys):
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        assert main(["run", "--state-dir", str(tmp_path / "state"), "--api-port", str(port)]) == 1
    err = capsys.readouterr().err
    assert f"api: cannot listen on 127.0.0.1:{port}" in err and "api.port" in err


# --- HTTPS ---------------------------------------------------------------------------------------


def test_https_with_the_daemons_own_certificate(tmp_path, start_service):
    tls = {"token": TOKEN, "tls_cert": str(TLS / "head-cert.pem"), "tls_key": str(TLS / "head-key.pem")}
    daemon = start_service(sim_head_config(tmp_path / "state", **tls))
    assert daemon.api_url.startswith("https://127.0.0.1:")
    # A client made from the head's config finds the URL and pins the daemon's certificate.
    pinned = ApiClient.for_config(load_config(SIM_IDEAL).with_state_dir(tmp_path / "state").with_api(**tls))
    assert pinned.url == daemon.api_url and pinned.state()["api"] == daemon.api_url
    assert next(pinned.events(after=0))["seq"] >= 1  # the event stream over TLS too
    assert pinned.set_exploration(False) is False
    # Any other client checks the name: the certificate names head.example, not 127.0.0.1.
    with pytest.raises(ApiError, match="head.example|match"):
        ApiClient(daemon.api_url, TOKEN, cafile=tls["tls_cert"]).state()
    # Nor do the system's CAs vouch for it.
    with pytest.raises(ApiError, match="CERTIFICATE_VERIFY_FAILED"):
        ApiClient(daemon.api_url, TOKEN).state()
    # Plain HTTP on the HTTPS port is answered with nothing the client could take for an answer.
    with pytest.raises(ApiError, match="cannot reach the daemon"):
        ApiClient(daemon.api_url.replace("https:", "http:"), TOKEN, timeout_s=3.0).state()
    assert pinned.state()["fixation"]["explore"] is False  # still serving


def test_a_certificate_the_server_cannot_use_is_an_error_at_start(tmp_path):
    config = load_config(SIM_IDEAL).with_state_dir(tmp_path).with_api(
        port=0, tls_cert=str(TLS / "head-cert.pem"), tls_key=str(TLS / "other-key.pem"))
    with pytest.raises(HeadctlError, match="api.tls_cert .*head-cert.pem, api.tls_key .*other-key.pem: "
                                            "cannot serve HTTPS"):
        serve(config).run(install_signals=False)
