"""The control API against a hostile client: can it be pushed into a 5xx, a loose type or an
unbounded resource?

Runs `headctl run` on the simulated head (configs/sim.yaml) in a child process with a
temporary state directory and `--api-port 0`, its output in a log file, and attacks it over
127.0.0.1 only:

1. schemathesis against the daemon's own `/openapi.json`: `--examples` generated requests per
   operation (valid and invalid: its positive and negative modes; no shrinking, no deadline),
   each answer checked for: no 5xx but 503; a status code and media type the schema documents;
   every 4xx/5xx the `{error, field, reason}` object; invalid data refused with a 4xx. The two
   streams (`/api/v1/events`, `/api/v1/eyes/{side}.mjpg`) answer without end and are left to
   step 2. Torque off, map resets and simulated faults are generated like the rest, after
   the others, and the head is put back (torque on, bus and cameras restored, exploration on)
   after each operation.
2. By hand: loose types; a 50 MB body announced by Content-Length, streamed by a client
   that does not wait, and chunked; malformed HTTP, a TLS hello, a 40 KB header, JSON nested
   20,000 deep, a 5,000-digit seed, NaN, invalid UTF-8, unknown methods, the streams' bad
   parameters; then `--half-open` connections at once (half with half a request line), which
   the daemon must close by itself, answering 408 (or 503 beyond its connection cap), while
   a request beside them is answered 503 and one after them 200.

At the end the daemon must still be running; it is stopped with SIGTERM and its log searched
for tracebacks. Figures: requests sent, answers by status, 5xx other than 503, check failures,
tracebacks, and the timings of the limits.

    .venv/bin/python -m benchmarks.hostile.api [--examples 500] [--half-open 300] [--max-seconds 1200]

Bounded: at most --examples per operation and --max-seconds in all (operations not started
by then are reported as skipped). Exits 1 on any 5xx but 503, check failure, traceback in the
daemon's log, or if the daemon dies.
"""
from __future__ import annotations

import argparse
import copy
import http.client
import json
import os
import selectors
import socket
import sys
import tempfile
import threading
import time
import urllib.parse
import urllib.request
from collections import Counter
from dataclasses import dataclass, field
from http import HTTPStatus
from pathlib import Path
from typing import Any, cast

import requests
import schemathesis
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from schemathesis import GenerationMode
from schemathesis.specs.openapi.checks import (content_type_conformance, negative_data_rejection,
                                               response_schema_conformance, status_code_conformance)

from benchmarks.support.daemon_process import BenchDaemon
from headctl.api.app import MAX_CONNECTIONS

ROOT = Path(__file__).resolve().parents[2]
STREAMS = {("GET", "/api/v1/events"), ("GET", "/api/v1/eyes/{side}.mjpg")}
# Those that change the head's state for the others come last.
OPERATIONS = [
    ("GET", "/api/v1/state"), ("GET", "/api/v1/learning"), ("GET", "/api/v1/eyes/{side}.jpg"),
    ("POST", "/api/v1/look/target"), ("POST", "/api/v1/look/angles"), ("GET", "/api/v1/looks/{look_id}"),
    ("DELETE", "/api/v1/looks/{look_id}"), ("POST", "/api/v1/exploration"), ("POST", "/api/v1/map/save"),
    ("POST", "/api/v1/map/load"), ("POST", "/api/v1/map/reset"), ("POST", "/api/v1/torque"),
    ("POST", "/api/v1/sim/faults"),
]


class BenchError(Exception):
    """A real failure: the daemon does not start or dies."""


@dataclass
class Tally:
    requests: int = 0
    statuses: Counter[int] = field(default_factory=Counter)
    failures: list[str] = field(default_factory=list)
    timings: dict[str, Any] = field(default_factory=dict)
    skipped: list[str] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def answer(self, what: str, status: int, content_type: str, body: bytes) -> None:
        """Count one answer and check it: no 5xx but 503, every refusal the error shape."""
        with self.lock:
            self.requests += 1
            self.statuses[status] += 1
        if status >= 500 and status != 503:
            self.fail(f"{what}: {status} {body[:200]!r}")
        if status >= 400:
            problem = error_shape_problem(status, content_type, body)
            if problem:
                self.fail(f"{what}: {status}: {problem}")

    def fail(self, message: str) -> None:
        with self.lock:
            self.failures.append(message)

    @property
    def server_errors(self) -> int:
        return sum(n for status, n in self.statuses.items() if status >= 500 and status != 503)


def error_shape_problem(status: int, content_type: str, body: bytes) -> str | None:
    if content_type.split(";")[0].strip() != "application/json":
        return f"content type {content_type!r}, not JSON"
    try:
        answer = json.loads(body)
    except ValueError:
        return f"not JSON: {body[:200]!r}"
    if not isinstance(answer, dict) or not {"error", "field", "reason"} <= set(answer):
        return f"not the error shape: {answer!r}"[:300]
    if answer["error"] != HTTPStatus(status).phrase or not answer["reason"] or b"Traceback" in body:
        return f"error {answer['error']!r}, reason {answer['reason']!r}"[:300]
    return None


# --- the daemon --------------------------------------------------------------------------------
class Daemon(BenchDaemon):
    def __init__(self, state_dir: Path) -> None:
        super().__init__(ROOT / "configs" / "sim.yaml", state_dir, BenchError)

    def wait_running(self, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        self.wait_url(deadline)
        while time.monotonic() < deadline:
            self.check_alive()
            if self.state() == "running":
                return
            time.sleep(0.1)
        raise BenchError(f"the daemon is not running after {timeout_s:.0f} s")

    def state(self) -> str | None:
        try:
            with urllib.request.urlopen(self.url + "/api/v1/state", timeout=10) as answer:
                return json.loads(answer.read())["state"]
        except (OSError, ValueError, KeyError):
            return None

    def stop(self, timeout_s: float = 30.0) -> int | None:
        return super().stop(timeout_s)

    def tracebacks(self) -> int:
        text = self.log_path.read_text(errors="replace")
        return text.count("Traceback (most recent call last)")


# --- 1. schemathesis ---------------------------------------------------------------------------


def restore(url: str) -> None:
    for path, body in (("/api/v1/sim/faults", {"fault": "restore_bus"}),
                       ("/api/v1/sim/faults", {"fault": "camera_resume", "camera": "left"}),
                       ("/api/v1/sim/faults", {"fault": "camera_resume", "camera": "right"}),
                       ("/api/v1/torque", {"enabled": True}), ("/api/v1/exploration", {"enabled": True})):
        requests.post(url + path, json=body, timeout=10)


def fuzz(daemon: Daemon, tally: Tally, examples: int, deadline: float) -> None:
    with urllib.request.urlopen(daemon.url + "/openapi.json", timeout=10) as answer:
        served = json.loads(answer.read())
    operations = {(method.upper(), path) for path, ops in served["paths"].items() for method in ops}
    if operations != set(OPERATIONS) | STREAMS:
        tally.fail(f"the schema's operations changed: {sorted(operations ^ (set(OPERATIONS) | STREAMS))}")
    schema = schemathesis.openapi.from_dict(copy.deepcopy(served), config=schemathesis.Config.from_dict({}))
    checks = [status_code_conformance, content_type_conformance, response_schema_conformance,
              negative_data_rejection]
    for method, path in OPERATIONS:
        if examples <= 0 or time.monotonic() > deadline:
            tally.skipped.append(f"{method} {path}")
            continue
        operation = schema[path][method]
        session = requests.Session()
        started, before = time.monotonic(), tally.requests
        strategy = st.one_of(operation.as_strategy(GenerationMode.POSITIVE),
                             operation.as_strategy(GenerationMode.NEGATIVE))

        @settings(max_examples=examples, deadline=None, database=None, phases=[Phase.explicit, Phase.generate],
                  suppress_health_check=list(HealthCheck))
        @given(case=strategy)
        def one(case: Any) -> None:
            what = f"{method} {path}"
            if time.monotonic() > deadline:
                return
            try:
                response = case.call(base_url=daemon.url, session=session, timeout=15)
            except requests.RequestException as err:
                tally.fail(f"{what}: no answer ({err})")
                return
            content_type = {k.lower(): v for k, v in response.headers.items()}.get("content-type", [""])
            tally.answer(what, response.status_code, content_type[0] if content_type else "", response.content)
            try:
                case.validate_response(response, checks=checks)
            except (Exception, BaseExceptionGroup) as err:  # a check failed: recorded, the run goes on
                tally.fail(f"{what}: {type(err).__name__}: {str(err)[:400]}")

        try:
            one()
        finally:
            session.close()
            restore(daemon.url)
        daemon.check_alive()
        print(f"  {method:6} {path:28} {tally.requests - before:5d} requests  {time.monotonic() - started:6.1f} s",
              flush=True)


# --- 2. by hand --------------------------------------------------------------------------------
def connect(url: str, timeout_s: float = 10.0) -> socket.socket:
    parts = urllib.parse.urlsplit(url)
    return socket.create_connection((parts.hostname, parts.port), timeout=timeout_s)


def read_to_eof(sock: socket.socket, timeout_s: float) -> tuple[bytes, float | None]:
    """What the server sends until it closes (and when: monotonic), or None if still open."""
    data = b""
    deadline = time.monotonic() + timeout_s
    while True:
        sock.settimeout(max(0.01, deadline - time.monotonic()))
        try:
            chunk = sock.recv(65536)
        except TimeoutError:
            return data, None
        except ConnectionResetError:
            chunk = b""
        if not chunk:
            return data, time.monotonic()
        data += chunk


def split_answer(data: bytes) -> tuple[int, str, bytes]:
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    headers = {k.strip().lower(): v.strip() for k, v in (line.split(":", 1) for line in lines[1:] if ":" in line)}
    return int(lines[0].split()[1]), headers.get("content-type", ""), body


def raw_exchange(tally: Tally, url: str, what: str, request: bytes, timeout_s: float = 10.0) -> int | None:
    """Send `request` bytes, read the answer to the connection's end; the status (None: no answer)."""
    with connect(url) as sock:
        try:
            sock.sendall(request)
        except OSError:
            pass
        data, closed = read_to_eof(sock, timeout_s)
    if not data:
        tally.fail(f"{what}: no answer")
        return None
    status, content_type, body = split_answer(data)
    tally.answer(what, status, content_type, body)
    if closed is None:
        tally.fail(f"{what}: the connection was left open {timeout_s} s after a refusal")
    return status


def request(tally: Tally, url: str, method: str, path: str, body: bytes | None = None,
            content_type: str = "application/json") -> int:
    parts = urllib.parse.urlsplit(url)
    conn = http.client.HTTPConnection(parts.hostname or "127.0.0.1", parts.port, timeout=15)
    try:
        conn.request(method, path, body=body, headers={"Content-Type": content_type} if body is not None else {})
        response = conn.getresponse()
        data = response.read()
        tally.answer(f"{method} {path} {(body or b'')[:60]!r}", response.status,
                     response.getheader("Content-Type", ""), data)
        return response.status
    finally:
        conn.close()


def expect(tally: Tally, what: str, status: int | None, wanted: int) -> None:
    if status != wanted:
        tally.fail(f"{what}: {status}, expected {wanted}")


def by_hand(daemon: Daemon, tally: Tally, half_open: int) -> None:
    url = daemon.url
    host = urllib.parse.urlsplit(url).hostname
    # Loose types and values that are no numbers.
    for path, sent in (("/api/v1/exploration", {"enabled": 0}), ("/api/v1/exploration", {"enabled": "yes"}),
                       ("/api/v1/torque", {"enabled": 0}), ("/api/v1/look/target", {"x": True, "y": 100, "d": 0}),
                       ("/api/v1/map/reset", {"seed": False}),
                       ("/api/v1/sim/faults", {"fault": "hardware_error", "joint": "pan", "bits": False}),
                       ("/api/v1/sim/faults", {"fault": "hardware_error"}), ("/api/v1/sim/faults", {"fault": "camera_stall"}),
                       ("/api/v1/look/angles", {"pan": "1", "tilt": 0, "vergence": 5}),
                       ("/api/v1/look/angles", {"pan": [1], "tilt": 0, "vergence": 5})):
        expect(tally, f"POST {path} {sent}", request(tally, url, "POST", path, json.dumps(sent).encode()), 422)
    for text in (b'{"x": NaN, "y": 1, "d": 0}', b'{"x": Infinity, "y": 1, "d": 0}', b'{"x": 1e999, "y": 1, "d": 0}'):
        expect(tally, f"target {text!r}", request(tally, url, "POST", "/api/v1/look/target", text), 422)
    seed = b'{"seed": ' + b"9" * 5000 + b"}"  # past Python's 4,300-digit int parsing limit: 400
    expect(tally, "a 5,000-digit seed", request(tally, url, "POST", "/api/v1/map/reset", seed), 400)
    expect(tally, "a 20-digit seed", request(tally, url, "POST", "/api/v1/map/reset", b'{"seed": 99999999999999999999}'),
           422)
    nested = b"[" * 20000 + b"]" * 20000
    status = request(tally, url, "POST", "/api/v1/look/target", nested)
    if status not in (400, 422):
        tally.fail(f"JSON nested 20,000 deep: {status}")
    expect(tally, "invalid UTF-8", request(tally, url, "POST", "/api/v1/look/target", b'{"x": "\xc3\x28"}'), 400)
    expect(tally, "form-encoded", request(tally, url, "POST", "/api/v1/exploration", b"enabled=true",
                                         "application/x-www-form-urlencoded"), 422)
    expect(tally, "a map name with a path", request(tally, url, "POST", "/api/v1/map/save",
                                                   b'{"name": "../../etc/x.npz"}'), 422)
    expect(tally, "a NUL in a map name", request(tally, url, "POST", "/api/v1/map/load", b'{"name": "a\\u0000.npz"}'),
           422)
    for method, path, wanted in (("OPTIONS", "/api/v1/state", 405), ("PATCH", "/api/v1/torque", 405),
                                 ("GET", "/api/v1/../../etc/passwd", 404), ("GET", "/api/v1/looks/1e3", 422),
                                 ("GET", "/api/v1/looks/99999999999999999999999", 404),
                                 ("GET", "/api/v1/learning?since=" + "9" * 5000, 422),
                                 ("GET", "/api/v1/events?after=-1", 422), ("GET", "/api/v1/eyes/left.mjpg?fps=0", 422),
                                 ("GET", "/api/v1/eyes/left.mjpg?fps=nan", 422), ("GET", "/api/v1/eyes/up.mjpg", 422)):
        expect(tally, f"{method} {path[:60]}", request(tally, url, method, path), wanted)

    # Malformed HTTP and an oversized head.
    for what, data, wanted in (
            ("a bad Content-Length", b"POST /api/v1/torque HTTP/1.1\r\nHost: h\r\nContent-Length: x\r\n\r\n", 400),
            ("Content-Length and chunked", b"POST /api/v1/torque HTTP/1.1\r\nHost: h\r\nContent-Length: 3\r\n"
                                           b"Transfer-Encoding: chunked\r\n\r\n", 400),
            ("a TLS hello", b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03" + os.urandom(64), 400),
            ("garbage", b"\x00\x01\x02 nonsense \r\n\r\n", 400),
            ("a 40 KB header", b"GET /api/v1/state HTTP/1.1\r\nHost: h\r\nX-Big: " + b"a" * 40000 + b"\r\n\r\n", 431),
            ("a WebSocket upgrade", b"GET /api/v1/events HTTP/1.1\r\nHost: h\r\nConnection: Upgrade\r\n"
                                    b"Upgrade: websocket\r\nSec-WebSocket-Version: 13\r\n"
                                    b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nContent-Length: 0\r\n\r\n", 200)):
        if wanted == 200:  # no WebSocket here: a plain answer (the stream), read briefly
            with connect(url) as sock:
                sock.sendall(data)
                sock.settimeout(5)
                first = sock.recv(65536)
            status, content_type, body = split_answer(first)
            tally.answer(what, status, content_type, body)
            expect(tally, what, status, 200)
            continue
        expect(tally, what, raw_exchange(tally, url, what, data), wanted)

    # 50 MB bodies.
    post = (b"POST /api/v1/look/target HTTP/1.1\r\nHost: h\r\nContent-Type: application/json\r\n"
            b"Content-Length: %d\r\n\r\n" % (50 << 20))
    started = time.monotonic()
    expect(tally, "50 MB by Content-Length", raw_exchange(tally, url, "50 MB by Content-Length", post), 413)
    tally.timings["413_by_content_length_ms"] = round(1000 * (time.monotonic() - started), 1)
    with connect(url) as sock:  # sent whole by a client that does not wait for an answer
        pushed, chunk = 0, b"1" * (1 << 20)
        started = time.monotonic()
        try:
            sock.sendall(post)
            while pushed < 50 << 20:
                pushed += sock.send(chunk)
        except OSError:
            pass
        tally.timings["streamed_50_mb"] = {"bytes_the_client_could_send": pushed,
                                           "until_the_server_closed_ms": round(1000 * (time.monotonic() - started), 1)}
        tally.requests += 1
        if pushed >= 50 << 20:
            tally.fail("a client could send all 50 MB")
    with connect(url) as sock:  # chunked, no Content-Length
        started = time.monotonic()
        pushed = 0
        sock.sendall(b"POST /api/v1/look/target HTTP/1.1\r\nHost: h\r\nContent-Type: application/json\r\n"
                     b"Transfer-Encoding: chunked\r\n\r\n")
        piece = b"%x\r\n" % (1 << 16) + b"1" * (1 << 16) + b"\r\n"
        try:
            while pushed < 50 << 20:
                sock.sendall(piece)
                pushed += 1 << 16
        except OSError:
            pass
        data, _ = read_to_eof(sock, 5.0)
        tally.timings["chunked_50_mb"] = {"bytes_the_client_could_send": pushed,
                                          "until_the_server_closed_ms": round(1000 * (time.monotonic() - started), 1)}
        if data:
            status, content_type, body = split_answer(data)
            tally.answer("50 MB chunked", status, content_type, body)
            expect(tally, "50 MB chunked", status, 413)
        else:
            tally.requests += 1  # reset before the 413 could be read: the client had not stopped sending
        if pushed >= 50 << 20:
            tally.fail("a chunked client could send all 50 MB")

    # Half-open connections: half silent, half with half a request line.
    started = time.monotonic()
    held: list[socket.socket] = []
    for i in range(half_open):
        sock = socket.create_connection((host, urllib.parse.urlsplit(url).port), timeout=10)
        if i % 2:
            sock.sendall(b"GET /api/v1/sta")
        held.append(sock)
    beside = request(tally, url, "GET", "/api/v1/state")
    expect(tally, "a request beside the half-open connections", beside, 503 if half_open >= MAX_CONNECTIONS else 200)
    tally.timings["half_open"] = {"connections": half_open, "a_request_beside_them": beside}
    # All read at once, so that each close is seen when it happens.
    closed_at: dict[int | None, list[float]] = {}  # by the status answered (None: closed without one)
    received = {sock: b"" for sock in held}
    with selectors.DefaultSelector() as selector:
        for sock in held:
            sock.setblocking(False)
            selector.register(sock, selectors.EVENT_READ)
        while selector.get_map() and time.monotonic() - started < 30.0:
            for key, _ in selector.select(timeout=0.5):
                ready = cast(socket.socket, key.fileobj)
                try:
                    chunk = ready.recv(65536)
                except BlockingIOError:
                    continue
                except ConnectionResetError:
                    chunk = b""
                if chunk:
                    received[ready] += chunk
                    continue
                selector.unregister(ready)
                answered: int | None = None
                if received[ready]:
                    answered, content_type, body = split_answer(received[ready])
                    tally.answer("half-open", answered, content_type, body)
                else:
                    tally.requests += 1
                closed_at.setdefault(answered, []).append(time.monotonic() - started)
        if selector.get_map():
            tally.fail(f"{len(selector.get_map())} half-open connections were still open after 30 s")
    for sock in held:
        sock.close()
    after = request(tally, url, "GET", "/api/v1/state")
    expect(tally, "a request after the half-open connections closed", after, 200)
    tally.timings["half_open"].update({
        "answers": {str(status): len(times) for status, times in closed_at.items()},
        "closed_after_s": {str(status): [round(min(times), 2), round(max(times), 2)]
                           for status, times in closed_at.items()},
        "a_request_after_them": after})


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--examples", type=int, default=500, help="generated requests per operation")
    parser.add_argument("--half-open", type=int, default=300, help="half-open connections held at once")
    parser.add_argument("--max-seconds", type=float, default=1200.0, help="bound on the generated part")
    parser.add_argument("--json", type=Path, help="write the figures here too")
    args = parser.parse_args()
    tally = Tally()
    with tempfile.TemporaryDirectory(prefix="hostile-api-") as tmp:
        daemon = Daemon(Path(tmp) / "state")
        started = time.monotonic()
        try:
            daemon.wait_running()
            print(f"daemon at {daemon.url}; schemathesis {schemathesis.__version__}, {args.examples} examples "
                  "per operation", flush=True)
            fuzz(daemon, tally, args.examples, started + args.max_seconds)
            fuzzed = tally.requests
            print("by hand ...", flush=True)
            by_hand(daemon, tally, args.half_open)
            daemon.check_alive()
            final_state = daemon.state()
        except BenchError as err:
            print(f"error: {err}", file=sys.stderr)
            daemon.stop()
            return 1
        finally:
            elapsed = time.monotonic() - started
        code = daemon.stop()
        figures = {
            "date": time.strftime("%Y-%m-%d"), "schemathesis": schemathesis.__version__,
            "examples_per_operation": args.examples, "operations": len(OPERATIONS) - len(tally.skipped),
            "skipped": tally.skipped, "requests": tally.requests, "generated_requests": fuzzed,
            "statuses": dict(sorted(tally.statuses.items())), "server_errors_not_503": tally.server_errors,
            "check_failures": len(tally.failures), "tracebacks_in_log": daemon.tracebacks(),
            "state_at_the_end": final_state, "exit_code": code, "seconds": round(elapsed, 1), **tally.timings,
            "failures": [failure.splitlines()[0][:200] for failure in tally.failures]}
    print(json.dumps(figures, indent=2))
    for failure in tally.failures[:20]:
        print("FAILURE:", failure)
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    bad = tally.server_errors or tally.failures or figures["tracebacks_in_log"] or final_state not in ("running", "degraded")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
