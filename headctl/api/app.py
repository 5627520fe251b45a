"""The daemon's HTTP control API and dashboard: the FastAPI app (`headctl.api.server` serves it).

Routes (docs/api.md); JSON but for the streams and the frames, under /api/v1:

    GET  /state                     joints, pose, fixation, learning, faults, servo loop, cameras
    GET  /learning?since=N          learning-curve points after point N
    POST /look/target               {x, y, d, wait_s?, replace?}: look at an image target
    POST /look/angles               {pan, tilt, vergence, relative?, wait_s?, replace?}
    GET  /looks/{id}?wait_s=S       a look's state (waits up to S s for it to finish)
    DELETE /looks/{id}              cancel a queued look
    POST /track                     {x, y} or {target: "fovea"}: pursue the patch there until stopped
    GET  /track                     the last track and the running one's figures
    DELETE /track?wait_s=S          stop the track
    GET  /events                    Server-Sent Events: saccade_onset, saccade_done,
                                    fixation_converged, fixation_refused, look_started, look_done,
                                    track_started, track_lost, track_stopped,
                                    fault, fault_cleared, exploration, torque, map
    POST /exploration, /torque      {enabled}
    POST /map/save, /map/load       {name?}; POST /map/reset {seed?}
    GET  /eyes/{left|right}.mjpg    MJPEG with the fovea and the last correspondence marked
    GET  /eyes/{left|right}.jpg     one such frame
    POST /sim/faults                fault injection, simulated head only
    GET  /metrics                   Prometheus exposition (not under /api/v1)
    GET  /                          the dashboard (headctl/api/dashboard/)

A refused request is a JSON object {"error", "field", "reason"} with a 4xx status, or 503
(the only 5xx), never a traceback. Request bodies are strict JSON (a bool is not a number, a
number or a string is not a bool). Limits a hostile client meets, held by `headctl.api.server`
and documented here: bodies over MAX_BODY_BYTES (413, refused before they are read), request
heads over MAX_HEAD_BYTES (431), a request not all arrived within REQUEST_TIMEOUT_S of its
connection or of its first byte (408, closed), and over MAX_CONNECTIONS open connections (503).
Bound to loopback by default; with a token configured every route but the dashboard's static
files needs `Authorization: Bearer <token>` (or `?token=`, for a browser's <img> and
EventSource). Nothing here holds a lock the servo loop waits on: state is read from the
latest-value slots, and motion goes through the look queue to the fixation thread.
"""
from __future__ import annotations

import asyncio
import hmac
import json
import logging
import threading
import time
from http import HTTPStatus
from pathlib import Path
from typing import AsyncIterator, Literal, TypeAlias, TypedDict

import cv2
import numpy as np
from fastapi import Depends, FastAPI, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field, model_validator
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException

from headctl.api.record import RecordControl, add_record_routes
from headctl.errors import ControlError, InvalidRequestError, NotFoundError, QueueFullError, UnavailableError
from headctl.json_types import JSON, JSONObject
from headctl.service.control import HeadService, SimFault
from headctl.service.events import Event, plain
from headctl.service.looks import LookJob, LookKind, LookRequest

log = logging.getLogger(__name__)

DASHBOARD_DIR = Path(__file__).resolve().parent / "dashboard"
MAX_WAIT_S = 60.0
SSE_PING_S = 15.0
MAX_BODY_BYTES = 64 * 1024  # the largest body a route takes is well under 1 KiB
MAX_HEAD_BYTES = 32 * 1024  # request line and headers
REQUEST_TIMEOUT_S = 10.0    # to send a whole request, from the connection (or its first byte when kept alive)
MAX_CONNECTIONS = 64        # open at once: the dashboard holds three streams, a tracker one or two


# --- request bodies ----------------------------------------------------------------------------
class _Body(BaseModel):
    # A misspelt key is an error, not ignored; strict: a bool is not a number nor a number or a
    # string a bool (an int is still a float); NaN and infinities are no coordinates.
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)


class _Waitable(_Body):
    wait_s: float = Field(0.0, ge=0.0, le=MAX_WAIT_S,
                          description="answer when the look is finished, or after this long (0: at once)")
    replace: bool = Field(False, description="cancel the looks still queued and stop the running one first")


class TargetLook(_Waitable):
    x: float = Field(description="column in the left image, px")
    y: float = Field(description="row in the left image, px")
    d: float | None = Field(None, description="disparity x_right - x_left, px; omitted: measured around "
                                             "(x, y) in the latest stereo pair, else 0 (the depth the eyes "
                                             "fixate) when the look can find the target by its patch")


class AnglesLook(_Waitable):
    pan: float | None = Field(None, description="deg")
    tilt: float | None = Field(None, description="deg")
    vergence: float | None = Field(None, description="deg, left eye minus right eye")
    relative: bool = False

    @model_validator(mode="after")
    def _complete(self) -> "AnglesLook":
        missing = [k for k in ("pan", "tilt", "vergence") if getattr(self, k) is None]
        if missing and not self.relative:
            raise ValueError(f"{', '.join(missing)} missing: an absolute look needs pan, tilt and vergence "
                             "(or send relative: true, where a missing angle means 0)")
        return self


class TrackTarget(_Body):
    x: float | None = Field(None, description="column in the left image, px (with y; omitted: target)")
    y: float | None = Field(None, description="row in the left image, px")
    target: Literal["fovea"] | None = Field(None, description='"fovea": what is on the left fovea now')

    @model_validator(mode="after")
    def _one_target(self) -> "TrackTarget":
        if (self.x is None) != (self.y is None):
            raise ValueError("send both x and y")
        if (self.x is None) == (self.target is None):
            raise ValueError('send x and y, or target: "fovea" (one of the two)')
        return self


class Switch(_Body):
    enabled: bool


class MapFile(_Body):
    name: str | None = Field(None, description="a file in the state directory (default: the checkpoint)")


class MapReset(_Body):
    seed: int | None = Field(None, ge=0, le=2**63 - 1, description="the random map's seed (default: gaze_map.seed)")


class Fault(_Body):
    fault: SimFault = Field(strict=False)  # strict would take only an enum member, never its JSON string
    joint: str | None = None
    camera: Literal["left", "right"] | None = None
    bits: int = Field(0, ge=0, le=255)


# --- errors ---------------------------------------------------------------------------------
class ErrorBody(BaseModel):
    """Every refusal: the HTTP reason phrase, the field at fault (or null), and why."""

    error: str
    field: str | None
    reason: str


ERROR_TEXT = {
    400: "not a valid HTTP request, or a body that is not text (not UTF-8)",
    401: "no token, or a wrong one",
    404: "no such look or map file",
    408: f"the request did not all arrive within {REQUEST_TIMEOUT_S:g} s (the connection is closed)",
    409: "not possible now (a map for another head, a look that has ended, no track to stop)",
    413: f"a body over {MAX_BODY_BYTES // 1024} KiB (refused before it is read; the connection is closed)",
    422: "a field missing, mistyped or out of range; malformed JSON",
    429: "the look queue is full",
    431: f"a request line and headers over {MAX_HEAD_BYTES // 1024} KiB (the connection is closed)",
    503: f"the daemon is not running (starting, stopping), or over {MAX_CONNECTIONS} connections are open",
}
# What any route may answer: the server's own limits, the token, and a daemon not running.
COMMON_ERRORS = (400, 401, 408, 413, 431, 503)
# A route's answers for its OpenAPI schema, by status: what FastAPI's `responses` takes.
Responses: TypeAlias = dict[int | str, dict[str, object]]
ERROR_RESPONSES: Responses = {
    code: {"model": ErrorBody, "description": ERROR_TEXT[code]} for code in COMMON_ERRORS}


def answers(*codes: int, ok: str | None = None, media_type: str | None = None,
            accepted: bool = False) -> Responses:
    """A route's answers beyond COMMON_ERRORS for its OpenAPI schema: its own refusals, 202 for
    a look not finished yet, and the 200's media type when it is not JSON."""
    documented: Responses = {
        code: {"model": ErrorBody, "description": ERROR_TEXT[code]} for code in codes}
    if ok is not None or media_type is not None:
        documented[200] = {"description": ok or "Successful Response"}
        if media_type is not None:
            documented[200]["content"] = {media_type: {"schema": {"type": "string", "format": "binary"}}}
    if accepted:
        documented[202] = {"description": "the look, not finished yet (queued or running): ask again by its id",
                           "content": {"application/json": {"schema": {"type": "object"}}}}
    return documented


def error_response(status: int, field: str | None, reason: str, *, close: bool = False, **extra: JSON) -> JSONResponse:
    """The answer to a refused request (`close`: and the connection closed after it)."""
    return JSONResponse({"error": HTTPStatus(status).phrase, "field": field, "reason": reason, **extra},
                        status_code=status, headers={"Connection": "close"} if close else None)


class FieldProblem(TypedDict):
    """One field a request got wrong, as a 422 answer lists it."""

    field: str | None
    reason: str


def _field_of(loc: tuple[int | str, ...]) -> str | None:
    parts = [str(p) for p in loc if p not in ("body", "query", "path", "header")]
    return ".".join(parts) or (str(loc[0]) if loc else None)


async def _on_invalid(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    errors: list[FieldProblem] = [{"field": _field_of(tuple(e.get("loc", ()))), "reason": str(e.get("msg", "invalid"))}
                                  for e in exc.errors()]
    first: FieldProblem = errors[0] if errors else {"field": None, "reason": "invalid request"}
    if any(e.get("type") == "json_invalid" for e in exc.errors()):
        first = {"field": "body", "reason": "the body is not valid JSON"}
    return error_response(422, first["field"], first["reason"], errors=errors)


# What each refusal of the service becomes; a ControlError of no other kind is a conflict.
CONTROL_STATUS: tuple[tuple[type[ControlError], int], ...] = (
    (InvalidRequestError, 422), (QueueFullError, 429), (NotFoundError, 404), (UnavailableError, 503),
    (ControlError, 409))


def control_status(exc: ControlError) -> int:
    return next(status for kind, status in CONTROL_STATUS if isinstance(exc, kind))


async def _on_control(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ControlError)
    return error_response(control_status(exc), exc.field, str(exc))


async def _on_http(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    headers = getattr(exc, "headers", None)
    field, reason = getattr(exc, "field", None), str(exc.detail)
    if exc.status_code == 400 and exc.__cause__ is not None:  # FastAPI could not read the body as JSON
        field, reason = "body", f"the body is not JSON text: {str(exc.__cause__)[:200]}"
    response = error_response(exc.status_code, field, reason)
    if headers:
        response.headers.update(headers)
    return response


async def _on_unexpected(request: Request, exc: Exception) -> JSONResponse:
    log.exception("%s %s failed", request.method, request.url.path)
    return error_response(500, None, f"internal error ({type(exc).__name__}); the daemon's log has the details")


class _Unauthorized(StarletteHTTPException):
    def __init__(self, reason: str) -> None:
        super().__init__(401, reason, headers={"WWW-Authenticate": 'Bearer realm="headctl"'})


# --- the eyes' images -------------------------------------------------------------------------
class EyeImages:
    """JPEG frames of each eye with the fovea (green cross) and the last correspondence (the
    matched point of the last fixation, yellow circle, with its confidence) marked; one encoding
    per camera frame, shared by every client."""

    def __init__(self, service: HeadService, quality: int) -> None:
        self.service = service
        self.quality = quality
        self._lock = threading.Lock()
        self._cache: dict[str, tuple[int, bytes]] = {}

    def jpeg(self, side: str) -> tuple[int, bytes] | None:
        frame = self.service.latest_frame(side)
        if frame is None:
            return None
        with self._lock:
            cached = self._cache.get(side)
        if cached is not None and cached[0] == frame.counter:
            return cached
        image = frame.image if frame.image.ndim == 3 else cv2.cvtColor(frame.image, cv2.COLOR_GRAY2BGR)
        image = image.copy()
        self._mark(image, side)
        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, self.quality])
        if not ok:
            return None
        encoded = (frame.counter, data.tobytes())
        with self._lock:
            self._cache[side] = encoded
        return encoded

    def _mark(self, image: np.ndarray, side: str) -> None:
        height, width = image.shape[:2]
        cx, cy = int(round((width - 1) / 2)), int(round((height - 1) / 2))
        arm = max(6, width // 40)
        cv2.drawMarker(image, (cx, cy), (0, 255, 0), cv2.MARKER_CROSS, 2 * arm, 2)  # 2 px: survives JPEG
        track = self.service.tracking_now()
        if track is not None and track["position"] is not None:  # the tracked patch, magenta
            x, y, d = track["position"]
            half = track["patch_size_px"] / 2.0
            x += d if side == "right" else 0.0
            cv2.rectangle(image, (int(round(x - half)), int(round(y - half))),
                          (int(round(x + half)), int(round(y + half))), (255, 0, 255), 2)
        last = self.service.last_fixation()
        if last is None or last.match is None:
            return
        eye = last.match.left if side == "left" else last.match.right
        point = (int(round(eye.x)), int(round(eye.y)))
        cv2.circle(image, point, arm, (0, 220, 255), 1, cv2.LINE_AA)
        cv2.putText(image, f"c={last.confidence:.2f}", (point[0] + arm + 2, point[1] + 4),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 220, 255), 1, cv2.LINE_AA)


# --- the app ---------------------------------------------------------------------------------
class JpegResponse(Response):
    media_type = "image/jpeg"


class MjpegResponse(StreamingResponse):
    media_type = "multipart/x-mixed-replace"


class EventStreamResponse(StreamingResponse):
    media_type = "text/event-stream"


def create_app(service: HeadService, token: str | None = None, stream_fps: float = 10.0,
               jpeg_quality: int = 80, recordings: RecordControl | None = None) -> FastAPI:
    """The API over `service` (a `headctl.service.control.ServiceControl`); `ApiServer` adds
    the body size cap (`headctl.api.server.BodyCap`) when it serves it."""
    app = FastAPI(title="headctl", version="1", docs_url=None, redoc_url=None, responses=ERROR_RESPONSES,
                  description="Control API of a calibration-free stereo camera head.")
    app.state.closing = threading.Event()
    app.state.streams = set()  # (loop, asyncio.Queue) of the open event streams
    eyes = EyeImages(service, jpeg_quality)

    def authorize(request: Request) -> None:
        if token is None:
            return
        header = request.headers.get("authorization", "")
        given = header[7:].strip() if header.lower().startswith("bearer ") else request.query_params.get("token")
        if given is None:
            raise _Unauthorized("a token is required: send 'Authorization: Bearer <token>' (or ?token=)")
        if not hmac.compare_digest(given.encode(), token.encode()):
            raise _Unauthorized("wrong token")

    app.add_exception_handler(RequestValidationError, _on_invalid)
    app.add_exception_handler(ControlError, _on_control)
    app.add_exception_handler(StarletteHTTPException, _on_http)
    app.add_exception_handler(Exception, _on_unexpected)
    guarded = [Depends(authorize)]

    # -- the dashboard ----------------------------------------------------------------
    @app.get("/", include_in_schema=False)
    def dashboard() -> Response:
        index = DASHBOARD_DIR / "index.html"
        if not index.exists():
            return error_response(404, None, f"{index}: the dashboard is not installed")
        return FileResponse(index, headers={"Cache-Control": "no-cache"})

    if DASHBOARD_DIR.is_dir():
        app.mount("/dashboard", StaticFiles(directory=DASHBOARD_DIR), name="dashboard")

    # -- state ------------------------------------------------------------------------
    state_cache = StateCache(service)

    @app.get("/api/v1/state", dependencies=guarded)
    async def state() -> Response:
        # On the event loop, not a worker thread: one thread fewer contending for the GIL.
        return Response(state_cache.body(), media_type="application/json")

    @app.get("/api/v1/learning", dependencies=guarded, responses=answers(422))
    def learning(since: int = Query(0, ge=0), limit: int = Query(5000, ge=0, le=5000)) -> Response:
        return _json(service.learning_since(since, limit))

    # -- looks ------------------------------------------------------------------------
    async def answer_look(job: LookJob, wait_s: float) -> Response:
        if wait_s > 0 and not job.done.is_set():
            await _wait_done(job, wait_s)
        body = plain(job.as_dict())
        return _json(body, status=200 if job.done.is_set() else 202)

    look_answers = answers(422, 429, ok="the look, finished (with wait_s)", accepted=True)

    @app.post("/api/v1/look/target", dependencies=guarded, responses=look_answers)
    async def look_target(body: TargetLook) -> Response:
        job = await run_in_threadpool(service.look, LookRequest(LookKind.TARGET, (body.x, body.y, body.d)),  # type: ignore[arg-type]
                                      body.replace)
        return await answer_look(job, body.wait_s)

    @app.post("/api/v1/look/angles", dependencies=guarded, responses=look_answers)
    async def look_angles(body: AnglesLook) -> Response:
        values = tuple(float(getattr(body, k) or 0.0) for k in ("pan", "tilt", "vergence"))
        job = await run_in_threadpool(service.look, LookRequest(LookKind.ANGLES, values, body.relative),  # type: ignore[arg-type]
                                      body.replace)
        return await answer_look(job, body.wait_s)

    @app.get("/api/v1/looks/{look_id}", dependencies=guarded,
             responses=answers(404, 422, ok="the look, finished", accepted=True))
    async def get_look(look_id: int,
                       wait_s: float = Query(0.0, ge=0.0, le=MAX_WAIT_S, allow_inf_nan=False)) -> Response:
        return await answer_look(service.get_look(look_id), wait_s)

    @app.delete("/api/v1/looks/{look_id}", dependencies=guarded,
                responses=answers(404, 409, 422, ok="the look, cancelled", accepted=True))
    async def cancel_look(look_id: int,
                          wait_s: float = Query(0.0, ge=0.0, le=MAX_WAIT_S, allow_inf_nan=False)) -> Response:
        # A queued look ends at once; a running one stops at its next servo cycle or frame wait.
        return await answer_look(service.cancel_look(look_id), wait_s)

    # -- tracks -----------------------------------------------------------------------
    @app.post("/api/v1/track", dependencies=guarded, responses=answers(422, 429, accepted=True))
    async def track(body: TrackTarget) -> Response:
        job = await run_in_threadpool(service.track, body.x, body.y)
        return await answer_look(job, 0.0)

    @app.get("/api/v1/track", dependencies=guarded, responses=answers(404, ok="the last track, with its figures"))
    def get_track() -> Response:
        return _json(plain(service.get_track()))

    @app.delete("/api/v1/track", dependencies=guarded,
                responses=answers(409, 422, ok="the track, stopped", accepted=True))
    async def stop_track(wait_s: float = Query(2.0, ge=0.0, le=MAX_WAIT_S, allow_inf_nan=False)) -> Response:
        return await answer_look(service.stop_track(), wait_s)

    # -- switches and the map ---------------------------------------------------------
    @app.post("/api/v1/exploration", dependencies=guarded, responses=answers(422))
    def exploration(body: Switch) -> Response:
        return _json({"enabled": service.set_exploration(body.enabled)})

    @app.post("/api/v1/torque", dependencies=guarded, responses=answers(409, 422))
    def torque(body: Switch) -> Response:
        return _json({"enabled": service.set_torque(body.enabled)})

    @app.post("/api/v1/map/save", dependencies=guarded, responses=answers(409, 422))
    def map_save(body: MapFile | None = None) -> Response:
        return _json(service.save_map(body.name if body else None))

    @app.post("/api/v1/map/load", dependencies=guarded, responses=answers(404, 409, 422))
    def map_load(body: MapFile | None = None) -> Response:
        return _json(service.load_map(body.name if body else None))

    @app.post("/api/v1/map/reset", dependencies=guarded, responses=answers(422))
    def map_reset(body: MapReset | None = None) -> Response:
        return _json(service.reset_map(body.seed if body else None))

    @app.post("/api/v1/sim/faults", dependencies=guarded, responses=answers(422))
    def inject(body: Fault) -> Response:
        return _json({"injected": service.inject_fault(body.fault, joint=body.joint, camera=body.camera,
                                                       bits=body.bits)})

    # -- streams ----------------------------------------------------------------------
    add_record_routes(app, recordings, guarded, answers)

    @app.get("/api/v1/events", dependencies=guarded, response_class=EventStreamResponse,
             responses=answers(422, ok="the events as they come (Server-Sent Events)", media_type="text/event-stream"))
    async def events(request: Request, after: int | None = Query(None, ge=0)) -> Response:
        last_id = request.headers.get("last-event-id")
        if after is None and last_id is not None and last_id.isdigit():
            after = int(last_id)
        return EventStreamResponse(_event_stream(app, service, after),
                                   headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})

    @app.get("/api/v1/eyes/{side}.jpg", dependencies=guarded, response_class=JpegResponse,
             responses=answers(422, ok="the eye's newest frame, marked", media_type="image/jpeg"))
    async def eye_jpeg(side: Literal["left", "right"]) -> Response:
        encoded = await run_in_threadpool(eyes.jpeg, side)
        if encoded is None:
            raise UnavailableError(f"camera {side}: no frame yet")
        return JpegResponse(encoded[1], headers={"Cache-Control": "no-cache"})

    @app.get("/api/v1/eyes/{side}.mjpg", dependencies=guarded, response_class=MjpegResponse,
             responses=answers(422, ok="the eye live, one JPEG a part", media_type="multipart/x-mixed-replace"))
    async def eye_mjpeg(side: Literal["left", "right"],
                        fps: float = Query(stream_fps, ge=0.1, le=60, allow_inf_nan=False)) -> Response:
        return MjpegResponse(_mjpeg(app, eyes, side, fps), media_type="multipart/x-mixed-replace; boundary=frame",
                             headers={"Cache-Control": "no-cache"})

    @app.get("/metrics", dependencies=guarded, include_in_schema=False)
    def metrics() -> Response:
        from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

        return Response(generate_latest(app.state.registry), media_type=CONTENT_TYPE_LATEST)

    from headctl.api.metrics import registry_for
    app.state.registry = registry_for(service)

    def openapi() -> JSONObject:
        # Every refusal is JSON, whatever the route's own media type (FastAPI would give an
        # error model the route's: image/jpeg for the eyes' frames).
        if app.openapi_schema is None:
            error_body = {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorBody"}}}
            for operations in FastAPI.openapi(app)["paths"].values():
                for operation in operations.values():
                    for code, answer in operation.get("responses", {}).items():
                        if code[:1] in ("4", "5"):
                            answer["content"] = error_body
        assert app.openapi_schema is not None
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
    return app


class StateCache:
    """The state's JSON, built again only once something happened (an event was published) or
    `max_age_s` passed: a hundred clients polling cost the daemon what ten would."""

    def __init__(self, service: HeadService, max_age_s: float = 0.1) -> None:
        self.service = service
        self.max_age_s = max_age_s
        self._cached: tuple[int, float, bytes] | None = None

    def body(self) -> bytes:
        seq, now = self.service.events.seq, time.monotonic()
        cached = self._cached
        if cached is None or cached[0] != seq or now - cached[1] > self.max_age_s:
            body = json.dumps(self.service.snapshot().as_dict(), default=_default, allow_nan=False).encode()
            self._cached = cached = (seq, now, body)
        return cached[2]


def _json(body: object, status: int = 200) -> Response:
    # NaN is no JSON: `plain` turns it into null before it gets here.
    return Response(json.dumps(body, default=_default, allow_nan=False), status_code=status,
                    media_type="application/json")


def _default(value: object) -> JSON:
    converted = plain(value)
    if converted is value:
        return str(value)
    return converted


async def _wait_done(job: LookJob, wait_s: float) -> None:
    """Wait for `job` to finish without holding a worker thread (its done callback wakes us)."""
    loop = asyncio.get_running_loop()
    finished = asyncio.Event()
    def wake(_job: LookJob) -> None:
        loop.call_soon_threadsafe(finished.set)

    job.add_done_callback(wake)
    try:
        await asyncio.wait_for(finished.wait(), wait_s)
    except asyncio.TimeoutError:
        pass


async def _event_stream(app: FastAPI, service: HeadService, after: int | None) -> AsyncIterator[bytes]:
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue[Event | None] = asyncio.Queue(maxsize=1024)
    lost = 0

    def put(event: Event | None) -> None:
        nonlocal lost
        try:
            queue.put_nowait(event)
        except asyncio.QueueFull:  # a client that does not read loses events, never blocks the head
            lost += 1

    entry = (loop, put)
    app.state.streams.add(entry)
    def deliver(event: Event) -> None:
        loop.call_soon_threadsafe(put, event)

    unsubscribe = service.events.subscribe(deliver, after_seq=after)
    try:
        yield b"retry: 2000\n: headctl events\n\n"
        while not app.state.closing.is_set():
            try:
                event = await asyncio.wait_for(queue.get(), SSE_PING_S)
            except asyncio.TimeoutError:
                yield b": ping\n\n"
                continue
            if event is None:  # the server is closing
                break
            if lost:
                yield f"event: lost\ndata: {json.dumps({'count': lost})}\n\n".encode()
                lost = 0
            data = json.dumps(event, default=_default, allow_nan=False)
            yield f"id: {event['seq']}\nevent: {event['type']}\ndata: {data}\n\n".encode()
    finally:
        unsubscribe()
        app.state.streams.discard(entry)


async def _mjpeg(app: FastAPI, eyes: EyeImages, side: str, fps: float) -> AsyncIterator[bytes]:
    period_s = 1.0 / fps
    last_counter = None
    while not app.state.closing.is_set():
        started = time.monotonic()
        encoded = await run_in_threadpool(eyes.jpeg, side)  # OpenCV encodes without the GIL
        if encoded is not None and encoded[0] != last_counter:
            last_counter = encoded[0]
            yield (b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: " + str(len(encoded[1])).encode()
                   + b"\r\n\r\n" + encoded[1] + b"\r\n")
        await asyncio.sleep(max(0.0, period_s - (time.monotonic() - started)))
