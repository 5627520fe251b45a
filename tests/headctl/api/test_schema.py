"""schemathesis against the running daemon's own OpenAPI schema.

One daemon on the simulated head (in this process, API on an ephemeral port) serves the
module; the schema is loaded from its `/openapi.json`, and every operation gets 25 generated
requests, valid and invalid (schemathesis's positive and negative modes), over loopback.
Each answer must be: no 5xx but 503; a status code the schema documents for the operation,
with the documented media type; every 4xx and 5xx an `{error, field, reason}` object;
invalid data refused with a 4xx.

Left out of the generated calls: the two streams (`/api/v1/events`, `/api/v1/eyes/{side}.mjpg`),
which answer without end; their refusals are tested here by hand. Torque off, map resets and
simulated faults are generated like anything else: those operations run after the others, and
the head is put back (torque on, bus and cameras restored, exploration on) after each
operation's examples, so that every operation meets a head that can move.
"""
from __future__ import annotations

import copy
import json
import urllib.request
from http import HTTPStatus
from typing import Any

import pytest
import requests
import schemathesis
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from schemathesis import GenerationMode
from schemathesis.specs.openapi.checks import (content_type_conformance, negative_data_rejection,
                                               response_schema_conformance, status_code_conformance)

from headctl.api.compose import serve
from tests.conftest import sim_head_config

pytestmark = pytest.mark.timeout(120)

EXAMPLES = 25
STREAMS = {("GET", "/api/v1/events"), ("GET", "/api/v1/eyes/{side}.mjpg")}
# Makes a bag in the directory a request names: by hand (tests/headctl/ros2/test_recorder.py), not at random.
BY_HAND = {("POST", "/api/v1/record/start")}
# Generated in this order: those that change the head's state for the others come last.
OPERATIONS = [
    ("GET", "/api/v1/state"), ("GET", "/api/v1/learning"), ("GET", "/api/v1/eyes/{side}.jpg"),
    ("POST", "/api/v1/look/target"), ("POST", "/api/v1/look/angles"), ("GET", "/api/v1/looks/{look_id}"),
    ("DELETE", "/api/v1/looks/{look_id}"), ("POST", "/api/v1/track"), ("GET", "/api/v1/track"),
    ("DELETE", "/api/v1/track"), ("POST", "/api/v1/exploration"), ("POST", "/api/v1/map/save"),
    ("POST", "/api/v1/map/load"), ("POST", "/api/v1/map/reset"), ("POST", "/api/v1/torque"),
    ("POST", "/api/v1/sim/faults"), ("GET", "/api/v1/record"), ("POST", "/api/v1/record/stop"),
]


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    with serve(sim_head_config(tmp_path_factory.mktemp("api-schema-state"))) as running:
        yield running


@pytest.fixture(scope="module")
def served_schema(daemon) -> dict[str, Any]:
    with urllib.request.urlopen(daemon.api_url + "/openapi.json", timeout=10) as answer:
        return json.loads(answer.read())


@pytest.fixture(scope="module")
def schema(served_schema):
    config = schemathesis.Config.from_dict({})  # no schemathesis.toml looked for
    return schemathesis.openapi.from_dict(copy.deepcopy(served_schema), config=config)


def media_type(response: Any) -> str:
    """The Content-Type's media type, of a requests or a schemathesis response (whose headers
    are lists)."""
    value = {k.lower(): v for k, v in response.headers.items()}.get("content-type", "")
    value = value[0] if isinstance(value, list) else value
    return value.split(";")[0].strip()


def check_answer(response: Any) -> None:
    status = response.status_code
    assert status < 500 or status == 503, f"{status}: {response.text[:500]}"
    if status >= 400:
        assert media_type(response) == "application/json", response.headers
        body = response.json()
        assert {"error", "field", "reason"} <= set(body), body
        assert body["error"] == HTTPStatus(status).phrase and isinstance(body["reason"], str) and body["reason"]
        assert body["field"] is None or isinstance(body["field"], str)
        assert "Traceback" not in response.text


def test_every_route_is_generated_or_a_stream_tested_by_hand(served_schema):
    served = {(method.upper(), path) for path, ops in served_schema["paths"].items() for method in ops}
    assert served == set(OPERATIONS) | STREAMS | BY_HAND


@pytest.mark.parametrize("method, path", OPERATIONS, ids=[f"{m} {p}" for m, p in OPERATIONS])
def test_generated_requests_get_documented_answers(daemon, schema, method, path):
    operation = schema[path][method]
    session = requests.Session()
    strategy = st.one_of(operation.as_strategy(GenerationMode.POSITIVE), operation.as_strategy(GenerationMode.NEGATIVE))

    @settings(max_examples=EXAMPLES, deadline=None, database=None, phases=[Phase.explicit, Phase.generate],
              suppress_health_check=list(HealthCheck), derandomize=True)
    @given(case=strategy)
    def one(case):
        response = case.call(base_url=daemon.api_url, session=session, timeout=10)
        check_answer(response)
        case.validate_response(response, checks=[status_code_conformance, content_type_conformance,
                                                 response_schema_conformance, negative_data_rejection])

    try:
        one()
    finally:
        session.close()
        restore(daemon)


def restore(daemon) -> None:
    """The head as before: torque on, the bus and both cameras back, exploration on."""
    for path, body in (("/api/v1/sim/faults", {"fault": "restore_bus"}),
                       ("/api/v1/sim/faults", {"fault": "camera_resume", "camera": "left"}),
                       ("/api/v1/sim/faults", {"fault": "camera_resume", "camera": "right"}),
                       ("/api/v1/torque", {"enabled": True}), ("/api/v1/exploration", {"enabled": True})):
        answer = requests.post(daemon.api_url + path, json=body, timeout=10)
        assert answer.status_code in (200, 503), answer.text  # 503: torque while the bus comes back


@pytest.mark.parametrize("path", ["/api/v1/events?after=-1", "/api/v1/events?after=x",
                                  "/api/v1/eyes/middle.mjpg", "/api/v1/eyes/left.mjpg?fps=0",
                                  "/api/v1/eyes/left.mjpg?fps=nan", "/api/v1/eyes/left.mjpg?fps=1e9"])
def test_the_streams_refuse_bad_parameters_before_streaming(daemon, path):
    response = requests.get(daemon.api_url + path, timeout=10)
    check_answer(response)
    assert response.status_code == 422


def test_the_streams_start_with_their_media_type(daemon):
    for path, expected in (("/api/v1/events?after=0", "text/event-stream"),
                           ("/api/v1/eyes/left.mjpg?fps=5", "multipart/x-mixed-replace")):
        with requests.get(daemon.api_url + path, stream=True, timeout=10) as response:
            assert response.status_code == 200 and media_type(response) == expected
            assert next(response.iter_content(64))
