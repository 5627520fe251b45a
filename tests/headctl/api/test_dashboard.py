"""The live dashboard (headctl/api/dashboard) in Debian's headless Chromium against the real daemon.

`headctl run` on the simulated head (configs/sim.yaml with an API token, the API on an
ephemeral port) in a subprocess; the page, opened as /?token=..., must load without a
JavaScript error or a refused request (every request it makes must carry the token), show
both eyes' live streams, the joint angles and a learning curve; its exploration and torque
buttons must change the service's state and show the new one, and an injected fault must
show while it lasts. Every wait is a WebDriverWait condition.
HEADCTL_SCREENSHOT=1 also writes docs/figures/dashboard.png.
"""
from __future__ import annotations

import importlib.util
import os
import pathlib
import time
import urllib.parse

import pytest
import yaml

from tests.support.daemon_proc import ROOT, SIM

CHROMIUM = pathlib.Path("/usr/bin/chromium")
CHROMEDRIVER = pathlib.Path("/usr/bin/chromedriver")
INSTALL = "./setup.sh test installs them (apt-get install chromium chromium-driver)"
SCREENSHOT = ROOT / "docs" / "figures" / "dashboard.png"
TOKEN = "dashboard-test-token-0123456789"

pytestmark = [pytest.mark.timeout(120), pytest.mark.slow]


def _require_browser() -> None:
    """Fail (not skip) naming the install step when the browser or its driver is missing."""
    missing = [str(p) for p in (CHROMIUM, CHROMEDRIVER) if not os.access(p, os.X_OK)]
    if missing:
        pytest.fail(f"{' and '.join(missing)} not found: {INSTALL}", pytrace=False)
    if importlib.util.find_spec("selenium") is None:
        pytest.fail("selenium is not installed: ./setup.sh test installs the test extra", pytrace=False)


@pytest.fixture(autouse=True)
def _browser_installed() -> None:
    """Checked before the daemon starts (autouse fixtures come first)."""
    _require_browser()


@pytest.fixture
def daemon(tmp_path, service_process):
    """`headctl run` on the simulated head, its API needing TOKEN; listening when yielded."""
    config = yaml.safe_load(SIM.read_text())
    config["api"] = {**(config.get("api") or {}), "token": TOKEN}
    config_path = tmp_path / "sim-token.yaml"
    config_path.write_text(yaml.safe_dump(config, sort_keys=False))
    proc = service_process(tmp_path / "state", config_path, token=TOKEN)
    try:
        proc.client       # waits for <state_dir>/api.url
        yield proc
    finally:
        if proc.proc.poll() is None:
            proc.terminate(10.0)
        print(f"--- daemon log (tail)\n{proc.tail(40)}")   # shown on failure
        proc.kill()


@pytest.fixture
def browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--disable-background-networking", "--disable-extensions", "--disable-sync",
                "--no-first-run", "--window-size=1400,1000"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    # The driver's path given explicitly: Selenium Manager never looks for (or downloads) one.
    driver = webdriver.Chrome(service=Service(executable_path=str(CHROMEDRIVER)), options=options)
    driver.set_page_load_timeout(20)
    try:
        yield driver
    finally:
        for entry in driver.get_log("browser"):   # what the test did not read; shown on failure
            print(f"browser {entry['level']}: {entry['message']}")
        driver.quit()     # before the daemon stops (fixtures end in reverse order): no stream left open


# Draws an <img> (the current frame of its MJPEG stream) on a canvas; returns its size and a
# hash of its pixels (FNV-1a over the RGBA bytes).
FRAME_HASH_JS = """
const img = document.getElementById(arguments[0]);
if (!img || !img.complete || !img.naturalWidth) return null;
const c = document.createElement('canvas');
c.width = img.naturalWidth; c.height = img.naturalHeight;
const ctx = c.getContext('2d');
ctx.drawImage(img, 0, 0);
const px = ctx.getImageData(0, 0, c.width, c.height).data;
let h = 0x811c9dc5;
for (let i = 0; i < px.length; i++) { h ^= px[i]; h = Math.imul(h, 0x01000193) >>> 0; }
return [c.width, c.height, h];
"""


def _severe(driver) -> list[str]:
    return [e["message"] for e in driver.get_log("browser") if e.get("level") == "SEVERE"]


def test_dashboard_live(daemon, browser):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    driver = browser
    wait = WebDriverWait(driver, 20, poll_frequency=0.1)
    driver.get(f"{daemon.url}/?token={urllib.parse.quote(TOKEN)}")
    assert "headctl" in driver.title

    def text(element_id: str) -> str:
        return driver.find_element(By.ID, element_id).text.strip()

    def number(element_id: str) -> float | None:
        try:
            return float(text(element_id))
        except ValueError:
            return None

    # the state arrives: service state and the joint angles as numbers
    wait.until(lambda d: text("service-state") not in ("", "connecting", "unreachable"))
    for element_id in ("joint-pan", "joint-tilt", "joint-left_eye", "joint-right_eye",
                       "pose-pan", "pose-tilt", "vergence", "fix-done", "fix-taught"):
        wait.until(lambda d, i=element_id: number(i) is not None, f"#{element_id} shows no number")

    # both eyes stream: the frame drawn at two moments at least 1 s apart differs
    for side in ("left", "right"):
        eye = f"eye-{side}"
        first = wait.until(lambda d, e=eye: d.execute_script(FRAME_HASH_JS, e), f"#{eye} shows no frame")
        assert first[0] > 0 and first[1] > 0, f"#{eye} is {first[0]} x {first[1]}"
        src = driver.find_element(By.ID, eye).get_attribute("src")
        assert src.startswith(f"{daemon.url}/api/v1/eyes/{side}.mjpg?") and f"token={TOKEN}" in src, src
        t0 = time.monotonic()
        wait.until(lambda d, e=eye: time.monotonic() - t0 >= 1.0
                   and (d.execute_script(FRAME_HASH_JS, e) or first)[2] != first[2],
                   f"#{eye} shows the same frame for 20 s")

    # a learning curve gets points; events arrive through the SSE stream
    wait.until(lambda d: int(d.find_element(By.ID, "curve-retinal").get_attribute("data-points") or 0) > 0,
               "#curve-retinal got no points")
    wait.until(lambda d: int(d.find_element(By.ID, "events").get_attribute("data-count") or 0) > 0,
               "#events got no server-sent event")

    # each toggle shows the server's state; a click flips it there (torque off asks first), and the
    # page shows the new state: off and back on (or on and back off)
    on_server = {"explore": lambda: daemon.status()["fixation"]["explore"],
                 "torque": lambda: daemon.status()["torque"]}
    for name, server_state in on_server.items():
        button = driver.find_element(By.ID, f"{name}-toggle")
        for _ in range(2):
            before = server_state()
            wait.until(lambda d: text(f"{name}-state") == ("on" if before else "off"),
                       f"#{name}-state does not show the server's state ({before})")
            wait.until(lambda d: button.is_enabled())
            button.click()
            if name == "torque" and before:
                wait.until(lambda d: d.switch_to.alert, "no confirmation before torque off").accept()
            wait.until(lambda d: server_state() != before, f"{name} is still {before} on the server")
            wait.until(lambda d: text(f"{name}-state") == ("off" if before else "on"),
                       f"#{name}-state does not show the new state")
            assert button.get_attribute("data-enabled") == str(not before).lower()

    # a click on the left eye looks there: the page turns the click into image pixels and sends a
    # target look without d (the daemon measures it), or says why there is none
    from selenium.webdriver.common.action_chains import ActionChains
    eye = driver.find_element(By.ID, "eye-left")
    width, height = eye.size["width"], eye.size["height"]
    ActionChains(driver).move_to_element_with_offset(eye, int(width / 4), -int(height / 8)).click().perform()
    wait.until(lambda d: eye.get_attribute("data-click-x"), "the click on the left eye was not taken")
    w, h = daemon.status()["image_size"]
    x, y = float(eye.get_attribute("data-click-x")), float(eye.get_attribute("data-click-y"))
    assert abs(x - 0.75 * w) <= 2 and abs(y - 3 / 8 * h) <= 2, f"clicked at 3/4, 3/8 of the frame; sent {x}, {y}"
    wait.until(lambda d: eye.get_attribute("data-look") or "no look at" in text("message"),
               "the click gave neither a look nor a reason")
    refused_click = not eye.get_attribute("data-look")
    if not refused_click:
        job = daemon.client.look(int(eye.get_attribute("data-look")))
        request = job["request"]
        assert (request["x"], request["y"]) == (x, y), request
        # d measured there, or (not measurable, the target findable) the look starts at the fixation depth.
        assert request["d_measured"] is True or request["d_reason"], request
        assert f"look {job['id']}" in text("message")
    else:
        # refused naming the field: d not measurable there, or (the head left near a pan limit by
        # exploring) the map's saccade to x, y beyond the joint limits
        message = text("message")
        assert "(d)" in message or ("(x)" in message and "beyond the joint limits" in message), message

    # with the track switch on, a click on the left eye starts a track there; the page's stop
    # button stops it on the server
    driver.find_element(By.ID, "track-mode").click()
    ActionChains(driver).move_to_element_with_offset(eye, 0, 0).click().perform()
    wait.until(lambda d: eye.get_attribute("data-track") or "no track at" in text("message"),
               "the click with the track switch on gave neither a track nor a reason")
    assert eye.get_attribute("data-track"), text("message")
    track = daemon.client.get_track()
    assert track["id"] == int(eye.get_attribute("data-track")) and track["request"]["kind"] == "track"
    assert abs(track["request"]["x"] - (w - 1) / 2) <= 2 and abs(track["request"]["y"] - (h - 1) / 2) <= 2
    stop = driver.find_element(By.ID, "track-stop")
    if daemon.client.get_track()["state"] in ("queued", "running"):
        wait.until(lambda d: stop.is_displayed(), "no stop button while the track runs")
        stop.click()
    wait.until(lambda d: daemon.client.get_track()["state"] not in ("queued", "running"), "the track did not stop")
    driver.find_element(By.ID, "track-mode").click()

    # a fault shows in the fault list (and as a fault event) while it lasts
    daemon.inject("bus_down")
    wait.until(lambda d: "servo bus down" in text("faults"), "#faults does not show the servo bus down")
    wait.until(lambda d: driver.find_elements(By.CSS_SELECTOR, "#events .k.fault"), "#events shows no fault event")
    daemon.inject("restore_bus")
    wait.until(lambda d: text("faults") == "none", "#faults still shows a fault after the bus came back")

    if os.environ.get("HEADCTL_SCREENSHOT") == "1":
        WebDriverWait(driver, 60, poll_frequency=0.5).until(
            lambda d: int(d.find_element(By.ID, "curve-retinal").get_attribute("data-points") or 0) >= 20)
        SCREENSHOT.parent.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(str(SCREENSHOT))

    severe = _severe(driver)
    if refused_click:  # the browser logs the refusal the page showed; that one is expected
        severe = [m for m in severe if not ("/api/v1/look/target" in m and "422" in m)]
    assert not severe, "JavaScript errors in the browser log:\n" + "\n".join(severe)
