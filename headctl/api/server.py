"""Serving the HTTP API: the `api-server` thread and the limits every connection is held to.

`ApiServer` runs uvicorn on a thread and event loop of its own, serving the app of
`headctl.api.app`, which holds the routes, the request models and the error shape. Here is what
concerns connections rather than routes, each limit answered in the API's error shape (its
defaults, `MAX_BODY_BYTES`, `MAX_HEAD_BYTES`, `REQUEST_TIMEOUT_S` and `MAX_CONNECTIONS`, are
`headctl.api.app`'s, which documents them in the OpenAPI schema):

- `BodyCap`, the middleware refusing a body over the limit with 413 before it is read;
- `GuardedHttpToolsProtocol`, uvicorn's HTTP protocol with a deadline for a whole request
  (408), a cap on the request line and headers (431), a cap on open connections (503), and
  400 for a request that cannot be parsed.
"""
from __future__ import annotations

import asyncio
import json
import logging
import socket
import ssl
import threading
import time
from http import HTTPStatus
from typing import cast

import uvicorn
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send
from uvicorn.config import Config as UvicornConfig
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol
from uvicorn.server import ServerState

from headctl.api.record import RecordControl
from headctl.api.app import MAX_BODY_BYTES, MAX_CONNECTIONS, MAX_HEAD_BYTES, REQUEST_TIMEOUT_S, create_app, error_response
from headctl.errors import HeadctlError
from headctl.service.control import HeadService

log = logging.getLogger(__name__)

OVER_CAP_GRACE_S = 1.0      # a connection beyond MAX_CONNECTIONS: this long to send its request (then 503)


# --- the request-size cap ----------------------------------------------------------------------
class _BodyTooLarge(StarletteHTTPException):
    field = "body"

    def __init__(self, max_bytes: int) -> None:
        super().__init__(413, f"the body is over {max_bytes} bytes, the most a request may send",
                         headers={"Connection": "close"})


class BodyCap:
    """ASGI middleware refusing request bodies over `max_bytes` with 413 before they are read:
    at once by their Content-Length, else (chunked) as soon as the bytes received pass it.

    An answer sent before the request's body was all received says `Connection: close`, so
    uvicorn closes the connection rather than read and discard the rest of the body."""

    def __init__(self, app: ASGIApp, max_bytes: int = MAX_BODY_BYTES) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared: int | None = None
        chunked = False
        for name, value in scope["headers"]:
            if name == b"content-length" and value.strip().isdigit():  # httptools refused any other
                declared = int(value)
            elif name == b"transfer-encoding":
                chunked = True
        if declared is not None and declared > self.max_bytes:
            await error_response(413, "body", f"the body ({declared} bytes) is over {self.max_bytes} bytes, "
                                              "the most a request may send", close=True)(scope, receive, send)
            return
        received = 0
        body_done = not (chunked or declared)
        started = False

        async def capped_receive() -> Message:
            nonlocal received, body_done
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                body_done = not message.get("more_body", False)
                if received > self.max_bytes:
                    raise _BodyTooLarge(self.max_bytes)
            return message

        async def closing_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
                headers = list(message.get("headers", ()))
                if not body_done and not any(name.lower() == b"connection" for name, _ in headers):
                    message = {**message, "headers": [*headers, (b"connection", b"close")]}
            await send(message)

        try:
            await self.app(scope, capped_receive, closing_send)
        except _BodyTooLarge as err:  # raised where no exception handler saw it
            if started:
                raise
            await error_response(413, "body", str(err.detail), close=True)(scope, receive, send)


# --- the server thread -------------------------------------------------------------------------
# uvicorn's messages about connections, in the daemon's log but for "Invalid HTTP request
# received.": that request is answered 400, and a client could write the log as fast as it sends.
_HTTP_LOG = logging.getLogger("headctl.api.app.http")
_HTTP_LOG.addFilter(lambda record: record.getMessage() != "Invalid HTTP request received.")


def _refusing(status: int, reason: str) -> ASGIApp:
    """An app refusing every request with `status` and closing the connection."""
    async def refuse(scope: Scope, receive: Receive, send: Send) -> None:
        await error_response(status, None, reason, close=True)(scope, receive, send)
    return refuse


class GuardedHttpToolsProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with the limits a hostile client meets, each answered in the
    API's error shape:

    - the whole request (head and body) must arrive within `request_timeout_s` of the connection
      being made, or of the request's first byte on a kept-alive connection: else 408 and the
      connection closed. uvicorn times out only kept-alive connections that are idle, so a
      client sending half a request line would hold a socket and a task forever;
    - a request line and headers over `max_head_bytes`: 431, as soon as that many bytes came
      without the head being complete (httptools would buffer them without end);
    - over `max_connections` connections open (uvicorn's `limit_concurrency`, answered here
      in JSON rather than by uvicorn in plain text): 503; a connection made beyond the cap has
      only OVER_CAP_GRACE_S to send its request (then 503 too, and closed);
    - a request httptools cannot parse: 400.

    `configured(...)` makes the class uvicorn is given (`http=`): uvicorn builds one instance
    per connection from (config, server_state, app_state)."""

    request_timeout_s = REQUEST_TIMEOUT_S
    max_head_bytes = MAX_HEAD_BYTES
    _last_cap_warning = 0.0  # monotonic time of the last "connections over the cap" warning

    @classmethod
    def configured(cls, request_timeout_s: float, max_head_bytes: int = MAX_HEAD_BYTES
                   ) -> type["GuardedHttpToolsProtocol"]:
        return cast("type[GuardedHttpToolsProtocol]", type(cls.__name__, (cls,), {
            "request_timeout_s": request_timeout_s, "max_head_bytes": max_head_bytes}))

    def __init__(self, config: UvicornConfig, server_state: ServerState, app_state: dict[str, object],
                 _loop: asyncio.AbstractEventLoop | None = None) -> None:
        super().__init__(config, server_state, app_state, _loop)
        self.logger = _HTTP_LOG
        self.max_connections = config.limit_concurrency
        self.limit_concurrency = None  # checked in on_headers_complete instead, answered in JSON
        self._read_timer: asyncio.TimerHandle | None = None
        self._head_bytes: int | None = None  # bytes received while a request's head is incomplete
        self._head_size = 0  # the request line's and headers' bytes, as parsed
        self._beyond_cap = False  # made while max_connections were open already

    def _over_cap(self) -> bool:
        return self.max_connections is not None and len(self.connections) > self.max_connections

    def _arm(self, seconds: float) -> None:
        self._disarm()
        self._read_timer = self.loop.call_later(seconds, self._timed_out)

    def _disarm(self) -> None:
        if self._read_timer is not None:
            self._read_timer.cancel()
            self._read_timer = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._beyond_cap = self._over_cap()
        self._arm(min(self.request_timeout_s, OVER_CAP_GRACE_S) if self._beyond_cap else self.request_timeout_s)

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self._read_timer is None:  # the next request on a kept-alive connection: its time starts now
            self._arm(self.request_timeout_s)
        super().data_received(data)
        if self._head_bytes is not None and not self.transport.is_closing():
            self._head_bytes += len(data)
            if self._head_bytes > self.max_head_bytes:
                self._refuse(431, f"the request line and headers are over {self.max_head_bytes} bytes")

    def on_message_begin(self) -> None:
        super().on_message_begin()
        self._head_bytes = 0
        self._head_size = 0

    def on_url(self, url: bytes) -> None:
        super().on_url(url)
        self._head_size += len(url)

    def on_header(self, name: bytes, value: bytes) -> None:
        super().on_header(name, value)
        self._head_size += len(name) + len(value) + 4

    def on_headers_complete(self) -> None:
        self._head_bytes = None
        if self._head_size > self.max_head_bytes:  # all in one read: parsed, but refused all the same
            self.app = _refusing(431, f"the request line and headers are over {self.max_head_bytes} bytes")
        elif self._over_cap():
            now = time.monotonic()
            if now - GuardedHttpToolsProtocol._last_cap_warning > 10.0:  # a flood is not a flood of warnings
                GuardedHttpToolsProtocol._last_cap_warning = now
                log.warning("api: over %d connections open; refusing requests with 503", self.max_connections)
            self.app = _refusing(503, f"over {self.max_connections} connections are open to the daemon; try again")
        else:
            self.app = self.config.loaded_app
        super().on_headers_complete()

    def on_message_complete(self) -> None:
        self._disarm()
        super().on_message_complete()

    def send_400_response(self, msg: str) -> None:
        self._refuse(400, "not a valid HTTP/1.1 request")

    def _unsupported_upgrade_warning(self) -> None:
        pass  # the API serves no WebSocket: an Upgrade header is ignored, and not worth a warning per request

    def _timed_out(self) -> None:
        self._read_timer = None
        if self._beyond_cap:
            self._refuse(503, f"over {self.max_connections} connections are open to the daemon; try again")
        else:
            self._refuse(408, f"the request did not all arrive within {self.request_timeout_s:g} s")

    def _refuse(self, status: int, reason: str) -> None:
        """Answer `status` in the API's error shape outside any request cycle, and close the
        connection. A request the app is still reading or answering ends (its receive() says
        disconnect); if an answer is on the wire already, there is no room for this one."""
        if self.transport is None or self.transport.is_closing():
            return
        cycle = self.cycle
        answering = bool(self.pipeline)
        if cycle is not None and not cycle.response_complete:
            answering = answering or cycle.response_started
            cycle.disconnected = True
            cycle.message_event.set()
        if not answering:
            body = json.dumps({"error": HTTPStatus(status).phrase, "field": None, "reason": reason}).encode()
            head = [f"HTTP/1.1 {status} {HTTPStatus(status).phrase}\r\n".encode()]
            head += [name + b": " + value + b"\r\n" for name, value in self.server_state.default_headers]
            head.append(b"content-type: application/json\r\ncontent-length: %d\r\nconnection: close\r\n\r\n"
                        % len(body))
            self.transport.write(b"".join(head) + body)
        self.transport.close()


class ApiServer(threading.Thread):
    """uvicorn serving `create_app(service)` behind `BodyCap`, on its own thread and event loop;
    a context manager.

    `__enter__` returns once the socket listens (the port is taken, or the address is wrong:
    HeadctlError naming it); `url` is then the address clients use (with port 0, the port
    the kernel chose). The limits on clients (`request_timeout_s`, `max_connections`,
    `max_body_bytes`, `max_head_bytes`) default to `headctl.api.app`'s constants."""

    def __init__(self, service: HeadService, host: str = "127.0.0.1", port: int = 8765, token: str | None = None,
                 stream_fps: float = 10.0, jpeg_quality: int = 80, tls_cert: str | None = None,
                 tls_key: str | None = None, *, request_timeout_s: float = REQUEST_TIMEOUT_S,
                 max_connections: int = MAX_CONNECTIONS, max_body_bytes: int = MAX_BODY_BYTES,
                 max_head_bytes: int = MAX_HEAD_BYTES, recordings: RecordControl | None = None) -> None:
        super().__init__(name="api-server", daemon=True)
        self.host, self.port = host, port
        self.tls_cert, self.tls_key = tls_cert, tls_key
        self.request_timeout_s, self.max_connections = request_timeout_s, max_connections
        self.max_head_bytes = max_head_bytes
        self.app = create_app(service, token=token, stream_fps=stream_fps, jpeg_quality=jpeg_quality,
                              recordings=recordings)
        self.app.add_middleware(BodyCap, max_bytes=max_body_bytes)
        self._sock: socket.socket | None = None
        self._server: uvicorn.Server | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self.url = ""
        self.error: BaseException | None = None

    def __enter__(self) -> "ApiServer":
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        # IPPROTO_TCP named: asyncio sets TCP_NODELAY on the accepted sockets only when the
        # listening socket says it is TCP; without it, every answer on a kept-open connection
        # waits ~40 ms for the client's delayed ACK.
        sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((self.host, self.port))
        except OSError as err:
            sock.close()
            raise HeadctlError(f"api: cannot listen on {self.host}:{self.port} ({err.strerror}); "
                               "is another headctl running? (api.port in the config)") from err
        sock.listen(128)
        sock.set_inheritable(True)
        self._sock = sock
        port = sock.getsockname()[1]
        host = {"0.0.0.0": "127.0.0.1", "::": "::1", "": "127.0.0.1"}.get(self.host, self.host)
        scheme = "https" if self.tls_cert else "http"
        self.url = f"{scheme}://[{host}]:{port}" if ":" in host else f"{scheme}://{host}:{port}"
        # No WebSocket protocol: the API serves none, so an Upgrade request is plain HTTP.
        config = uvicorn.Config(self.app, log_level="warning", access_log=False, lifespan="off",
                                timeout_graceful_shutdown=2, ws="none", limit_concurrency=self.max_connections,
                                http=GuardedHttpToolsProtocol.configured(self.request_timeout_s, self.max_head_bytes),
                                ssl_certfile=self.tls_cert, ssl_keyfile=self.tls_key)
        try:
            config.load()  # the TLS context: a bad certificate is an error now, not in the thread
        except (OSError, ssl.SSLError) as err:
            sock.close()
            self._sock = None
            raise HeadctlError(f"api.tls_cert {self.tls_cert}, api.tls_key {self.tls_key}: "
                               f"cannot serve HTTPS ({err})") from err
        self._server = uvicorn.Server(config)
        self.start()
        log.info("control API and dashboard on %s", self.url)
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def run(self) -> None:
        assert self._server is not None and self._sock is not None
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._server.serve(sockets=[self._sock]))
        except Exception as err:  # reported through the status, never lost
            self.error = err
            log.exception("%s: the API server failed", self.name)
        finally:
            loop.close()

    def stop(self, timeout_s: float = 4.0) -> None:
        """End the streams, stop serving, close the socket. Safe to call twice."""
        self.app.state.closing.set()
        for loop, put in list(self.app.state.streams):
            try:
                loop.call_soon_threadsafe(put, None)
            except RuntimeError:  # its loop is already closed
                pass
        if self._server is not None:
            self._server.should_exit = True
        if self.is_alive() and threading.current_thread() is not self:
            self.join(timeout_s)
            if self.is_alive():
                log.warning("%s did not stop within %.1f s", self.name, timeout_s)
        if self._sock is not None:
            self._sock.close()
            self._sock = None
