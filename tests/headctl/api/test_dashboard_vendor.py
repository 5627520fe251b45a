"""The dashboard's vendored chart library (uPlot, headctl/api/dashboard/vendor/) served by the
API's static route with the page, with its licence, also when the API needs a token; and every
file of the dashboard, the vendored ones too, in the package data a wheel carries."""
from __future__ import annotations

import fnmatch
import http.client
import re
import tomllib
import urllib.parse
from collections.abc import Iterator

import pytest

from headctl.api.app import DASHBOARD_DIR
from headctl.api.server import ApiServer
from headctl.service.events import EventHub
from tests.support.daemon_proc import ROOT

VENDOR = DASHBOARD_DIR / "vendor"
TOKEN = "vendor-test-token-0123456789"


class _NoService:
    """The static routes ask nothing of the service."""

    events = EventHub()


@pytest.fixture(scope="module")
def api() -> Iterator[ApiServer]:
    with ApiServer(_NoService(), port=0, token=TOKEN) as server:  # type: ignore[arg-type]
        yield server


def get(server: ApiServer, path: str) -> tuple[int, str, bytes]:
    parts = urllib.parse.urlsplit(server.url)
    conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=10)
    try:
        conn.request("GET", path)
        response = conn.getresponse()
        return response.status, response.getheader("Content-Type", ""), response.read()
    finally:
        conn.close()


@pytest.mark.parametrize("name, media_type", [("uPlot.iife.min.js", "javascript"), ("uPlot.min.css", "text/css"),
                                              ("uPlot.LICENSE", "")])
def test_the_vendored_files_are_served_as_they_are(api: ApiServer, name: str, media_type: str) -> None:
    status, content_type, body = get(api, f"/dashboard/vendor/{name}")  # no token: the page's own files
    assert status == 200 and media_type in content_type, (status, content_type)
    assert body == (VENDOR / name).read_bytes()


def test_the_licence_is_uplot_s_mit_licence_and_the_library_its_release(api: ApiServer) -> None:
    licence = get(api, "/dashboard/vendor/uPlot.LICENSE")[2].decode()
    assert licence.startswith("The MIT License") and "Leon Sorokin" in licence
    assert "THE SOFTWARE IS PROVIDED \"AS IS\"" in licence
    banner = get(api, "/dashboard/vendor/uPlot.iife.min.js")[2][:80].decode()
    assert re.match(r"/\*! https://github\.com/leeoniya/uPlot \(v1\.6\.\d+\) \*/", banner), banner


def test_the_page_loads_the_library_before_its_own_script(api: ApiServer) -> None:
    page = get(api, "/")[2].decode()
    scripts = re.findall(r'<script src="([^"]+)"', page)
    assert scripts == ["/dashboard/vendor/uPlot.iife.min.js", "/dashboard/dashboard.js"], scripts
    assert '<link rel="stylesheet" href="/dashboard/vendor/uPlot.min.css">' in page
    assert not re.search(r'(src|href)="(https?:)?//', page), "the page loads something from elsewhere"


def test_every_dashboard_file_is_package_data() -> None:
    patterns = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["headctl"]
    package = ROOT / "headctl"
    files = [p.relative_to(package).as_posix() for p in DASHBOARD_DIR.rglob("*") if p.is_file()
             and "__pycache__" not in p.parts]
    assert any(f.startswith("api/dashboard/vendor/") for f in files)
    missing = [f for f in files if not any(fnmatch.fnmatch(f, pat) and f.count("/") == pat.count("/")
                                           for pat in patterns)]
    assert not missing, f"not in [tool.setuptools.package-data] headctl: {missing}"
