"""A small client of the daemon's HTTP API (standard library only): what `headctl status` and
`headctl look` use, and what a Python program on the robot can import.

    from headctl.api.client import ApiClient
    head = ApiClient.for_config("configs/my-head.yaml")
    job = head.look_target(160, 120, -4, wait_s=10)
    print(job["state"], job["result"].get("landing_error_px"))

Where the daemon listens: `--url`, else `<state_dir>/api.url` (written by the running
daemon, so an ephemeral port is found too), else the config's `api.host`/`api.port`. The
token: `--token`, else `$HEADCTL_TOKEN`, else the config's `api.token`/`api.token_file`.
HTTPS: the server's certificate is checked against `cafile` (`--cacert`), else the system's
CAs; a client made from the daemon's own config pins the daemon's certificate instead.
"""
from __future__ import annotations

import http.client
import json
import os
import ssl
import urllib.error
import urllib.parse
import urllib.request
from typing import Iterator

from headctl.config.head import HeadConfig
from headctl.errors import HeadctlError
from headctl.json_types import JSON, JSONObject


class ApiError(HeadctlError):
    """The daemon refused a request (`status`, `field`, `reason` from its answer) or cannot be reached."""

    def __init__(self, message: str, status: int | None = None, field: str | None = None,
                 reason: str | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.field = field
        self.reason = reason


class ApiClient:
    def __init__(self, url: str, token: str | None = None, timeout_s: float = 5.0, cafile: str | None = None,
                 check_hostname: bool = True) -> None:
        self.url = url.rstrip("/")
        self.token = token
        self.timeout_s = timeout_s
        self.tls: ssl.SSLContext | None = None
        if self.url.startswith("https:"):
            try:
                self.tls = ssl.create_default_context(cafile=cafile)
            except (OSError, ssl.SSLError) as err:
                raise ApiError(f"{cafile}: cannot read the CA certificate ({err})") from err
            self.tls.check_hostname = check_hostname

    @classmethod
    def for_config(cls, config: HeadConfig, url: str | None = None, token: str | None = None,
                   timeout_s: float = 5.0, cafile: str | None = None) -> "ApiClient":
        if url is None:
            try:
                url = config.api_url_path.read_text(encoding="utf-8").strip() or None
            except OSError:
                url = None
        if url is None:
            if not config.api.enabled:
                raise ApiError(f"{config.path}: api.enabled is false: the daemon has no API to ask")
            url = config.api.url
        token = token or os.environ.get("HEADCTL_TOKEN") or config.api.token
        if cafile is None and config.api.tls_cert:
            # The daemon's own certificate as the only trust anchor (pinned): no other server can
            # show it, so its name need not match the address (127.0.0.1 for a 0.0.0.0 bind).
            return cls(url, token, timeout_s, cafile=config.api.tls_cert, check_hostname=False)
        return cls(url, token, timeout_s, cafile=cafile)

    # -- the routes ---------------------------------------------------------------------
    def state(self) -> JSONObject:
        return self.request("GET", "/api/v1/state")

    def learning(self, since: int = 0) -> JSONObject:
        return self.request("GET", f"/api/v1/learning?since={since}")

    def look_target(self, x: float, y: float, d: float | None = None, wait_s: float = 0.0,
                    replace: bool = False) -> JSONObject:
        """Fixate the image target (x, y, d); `d` None: the daemon measures it at (x, y)."""
        body: JSONObject = {"x": x, "y": y, "wait_s": wait_s, "replace": replace}
        if d is not None:
            body["d"] = d
        return self.request("POST", "/api/v1/look/target", body, wait_s=wait_s)

    def look_angles(self, pan: float, tilt: float, vergence: float, relative: bool = False, wait_s: float = 0.0,
                    replace: bool = False) -> JSONObject:
        return self.request("POST", "/api/v1/look/angles",
                            {"pan": pan, "tilt": tilt, "vergence": vergence, "relative": relative,
                             "wait_s": wait_s, "replace": replace}, wait_s=wait_s)

    def look(self, look_id: int, wait_s: float = 0.0) -> JSONObject:
        return self.request("GET", f"/api/v1/looks/{look_id}?wait_s={wait_s}", wait_s=wait_s)

    def cancel_look(self, look_id: int, wait_s: float = 0.0) -> JSONObject:
        """Cancel a queued look, or stop a running one (waiting up to `wait_s` for it to stop)."""
        return self.request("DELETE", f"/api/v1/looks/{look_id}?wait_s={wait_s}", wait_s=wait_s)

    def track(self, x: float | None = None, y: float | None = None) -> JSONObject:
        """Pursue the patch at (x, y) of the left image (None: what is on the fovea) until stopped."""
        body: JSONObject = {"target": "fovea"} if x is None or y is None else {"x": x, "y": y}
        return self.request("POST", "/api/v1/track", body)

    def get_track(self) -> JSONObject:
        """The last track and, while it runs, its figures so far."""
        return self.request("GET", "/api/v1/track")

    def stop_track(self, wait_s: float = 2.0) -> JSONObject:
        return self.request("DELETE", f"/api/v1/track?wait_s={wait_s}", wait_s=wait_s)

    def record_start(self, directory: str | None = None, seconds: float | None = None) -> JSONObject:
        body: JSONObject = {"directory": directory, "seconds": seconds}
        return self.request("POST", "/api/v1/record/start", {k: v for k, v in body.items() if v is not None})

    def record_stop(self) -> JSONObject:
        return self.request("POST", "/api/v1/record/stop", {})

    def record_status(self) -> JSONObject:
        return self.request("GET", "/api/v1/record")

    def set_exploration(self, enabled: bool) -> bool:
        return bool(self.request("POST", "/api/v1/exploration", {"enabled": enabled})["enabled"])

    def set_torque(self, enabled: bool) -> bool:
        return bool(self.request("POST", "/api/v1/torque", {"enabled": enabled})["enabled"])

    def events(self, after: int | None = None, timeout_s: float = 30.0) -> Iterator[JSONObject]:
        """The event stream, one event (its JSON data) at a time, until the server closes it."""
        path = "/api/v1/events" + (f"?after={after}" if after is not None else "")
        parts = urllib.parse.urlsplit(self.url)
        host = parts.hostname or "127.0.0.1"
        conn = (http.client.HTTPSConnection(host, parts.port, timeout=timeout_s, context=self.tls)
                if self.tls is not None else http.client.HTTPConnection(host, parts.port, timeout=timeout_s))
        try:
            conn.request("GET", path, headers=self._headers())
            response = conn.getresponse()
            if response.status != 200:
                raise self._refusal(response.status, response.read())
            data: list[str] = []
            for raw in response:
                line = raw.decode("utf-8").rstrip("\r\n")
                if line.startswith("data:"):
                    data.append(line[5:].strip())
                elif not line and data:
                    event: JSONObject = json.loads("\n".join(data))
                    yield event
                    data = []
        finally:
            conn.close()

    # -- plumbing -----------------------------------------------------------------------
    def _headers(self) -> dict[str, str]:
        headers = {"Accept": "application/json"}
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        return headers

    def request(self, method: str, path: str, body: JSONObject | None = None, wait_s: float = 0.0) -> JSONObject:
        """The daemon's answer to `method path` (every route answers a JSON object)."""
        data = None if body is None else json.dumps(body).encode()
        headers = self._headers()
        if data is not None:
            headers["Content-Type"] = "application/json"
        req = urllib.request.Request(self.url + path, data=data, method=method, headers=headers)
        try:
            with urllib.request.urlopen(req, timeout=self.timeout_s + wait_s, context=self.tls) as response:
                answer: JSONObject = json.loads(response.read())
                return answer
        except urllib.error.HTTPError as err:
            raise self._refusal(err.code, err.read()) from None
        except (urllib.error.URLError, OSError, http.client.HTTPException) as err:
            reason = getattr(err, "reason", None) or repr(err)
            raise ApiError(f"{self.url}: cannot reach the daemon ({reason}); is `headctl run` running "
                           "with this config (and is it http, or https)?") from err

    def _refusal(self, status: int, payload: bytes) -> ApiError:
        answer: JSON
        try:
            answer = json.loads(payload)
        except ValueError:
            answer = {"reason": payload.decode(errors="replace")[:200]}
        field, reason = answer.get("field"), answer.get("reason", "")
        where = f" ({field})" if field else ""
        return ApiError(f"{self.url}: {status} {answer.get('error', '')}{where}: {reason}", status, field, reason)
