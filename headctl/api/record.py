"""The recording routes: `POST /api/v1/record/start`, `POST /api/v1/record/stop`,
`GET /api/v1/record` (a rosbag2 bag of the service's topics, `headctl.ros2.recorder`)."""
from __future__ import annotations

from typing import Any, Protocol

from fastapi import FastAPI
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, Field
from starlette.concurrency import run_in_threadpool

from headctl.errors import UnavailableError
from headctl.json_types import JSONObject


class RecordControl(Protocol):
    """What the routes need of the recordings (`headctl.ros2.recorder.Recordings`)."""

    def start(self, directory: str | None = None, seconds: float | None = None) -> JSONObject: ...

    def stop(self, timeout_s: float = 5.0) -> JSONObject: ...

    def status(self) -> JSONObject: ...


class RecordStart(BaseModel):
    model_config = ConfigDict(extra="forbid")
    # the directory the bag is made in (absolute; default ros2.recording.directory)
    directory: str | None = Field(None, min_length=1, max_length=4096)
    # stop by itself after this long (default: until POST /api/v1/record/stop)
    seconds: float | None = Field(None, gt=0, allow_inf_nan=False)


def add_record_routes(app: FastAPI, recordings: RecordControl | None, guarded: list[Any],
                      answers: Any) -> None:
    def control() -> RecordControl:
        if recordings is None:
            raise UnavailableError("recording is not available in this service (rosbags is not installed: "
                                   "pip install rosbags)")
        return recordings

    @app.post("/api/v1/record/start", dependencies=guarded, responses=answers(409, 422))
    async def record_start(body: RecordStart) -> JSONResponse:
        return JSONResponse(await run_in_threadpool(control().start, body.directory, body.seconds))

    @app.post("/api/v1/record/stop", dependencies=guarded, responses=answers(409))
    async def record_stop() -> JSONResponse:
        return JSONResponse(await run_in_threadpool(control().stop))

    @app.get("/api/v1/record", dependencies=guarded)
    async def record_status() -> JSONResponse:
        return JSONResponse(control().status())
