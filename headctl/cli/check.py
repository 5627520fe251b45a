"""`headctl check`'s connection report: every part of a head tried, one line each.

The servo bus is opened and read, and each servo reported (its position, temperature,
voltage and hardware errors, or why it does not answer, with its id and port); the USB
adapter's latency timer where sysfs tells it; then each camera opened and streamed (its
first frame, or the failure naming the camera), and what it can do about its exposure.
A part that fails does not stop the others: a missing adapter still leaves the cameras
tried. Exit 0 when every part works, 1 when any failed; a warning (a camera that can
neither hold nor fix its exposure) costs fixations, not the head, and fails nothing.
"""
from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass

from drivers.cameras.camera import Camera, ExposureMode
from drivers.dynamixel.sdk import adapter_latency_timer_ms
from drivers.errors import DriverError
from drivers.servo.bus import ServoBus
from drivers.servo.joints import JOINTS
from headctl.config.head import HeadConfig

SYSFS = "/sys"  # where the kernel's sysfs is mounted (tests point it elsewhere)
SERVO_RULES = "udev/99-headctl-servos.rules"
# The adapter holds a servo's short reply until its latency timer runs out (an FTDI chip sends
# a partly filled USB packet only then; FTDI AN232B-04), so every read of the servo loop waits
# that long; more than half the loop's period leaves no room for the write and the host's work.
LATENCY_SHARE_OF_PERIOD = 0.5


@dataclass
class Report:
    """The lines printed, and how many parts failed or warned."""

    failures: int = 0
    warnings: int = 0

    def ok(self, part: str, text: str) -> None:
        print(f"  {part}: {text}")

    def failed(self, part: str, text: str) -> None:
        print(f"  {part}: FAILED: {text}")
        self.failures += 1

    def warn(self, part: str, text: str) -> None:
        print(f"  {part}: WARNING: {text}")
        self.warnings += 1

    def end(self) -> int:
        warned = f" ({self.warnings} warning(s))" if self.warnings else ""
        print(f"check: OK{warned}" if not self.failures else f"check: {self.failures} problem(s){warned}")
        return 0 if not self.failures else 1


def connect_and_report(config: HeadConfig, timeout_s: float) -> int:
    """Try every servo and camera of `config`, printing a line per part; the exit status."""
    from headctl.service.build import HeadDevices

    report = Report()
    try:
        devices = HeadDevices.build(config)  # as `run` builds them (the simulated head's too)
    except (DriverError, OSError) as err:  # `_prepare` built them already: not the config's fault
        report.failed("devices", str(err))
        return report.end()
    with contextlib.ExitStack() as stack:
        assert devices.bus is not None  # built here, not owned by a servo process
        report_servos(config, devices.bus, stack, report)
        report_latency_timer(config, report)
        for side, camera in devices.cameras.items():
            report_camera(side, camera, stack, timeout_s, report)
    return report.end()


def report_servos(config: HeadConfig, bus: ServoBus, stack: contextlib.ExitStack, report: Report) -> None:
    """The bus opened and read once; a line per joint, whatever failed."""
    port = config.servo_bus.port
    try:
        stack.enter_context(bus)
        state = bus.read_state()
    except (DriverError, OSError) as err:
        report.failed("servo bus", str(err))
        for joint in JOINTS:
            report.failed(f"joint {joint} (id {config.servo_bus.joints[joint].servo_id}) on {port}",
                          "not reached: the bus did not open")
        return
    missing = bus.missing
    for joint in JOINTS:
        if joint in missing:
            report.failed(bus.describe(joint), f"not answering ({missing[joint].reason})")
            continue
        jc, js = config.servo_bus.joints[joint], state[joint]
        line = (f"{jc.model}, at {js.position:.2f} deg (limits {jc.min_angle:g}..{jc.max_angle:g}), "
                f"{js.temperature_c:.0f} C, {js.input_voltage_v:.1f} V")
        if js.hardware_error_bits:
            report.failed(bus.describe(joint), f"{line}, {', '.join(js.hardware_errors)}")
        else:
            report.ok(bus.describe(joint), f"{line}, no hardware error")
    # What the read itself recovered from (a servo rebooted inside it) reads clear in the
    # state: the bus's fault log still tells it.
    latest = {r.episode: r for r in bus.fault_log.since(0)}  # each episode as it stands now
    for episode in latest.values():
        if not episode.is_open:  # an open one shows in the state above
            report.failed(bus.describe(episode.joint),
                          f"had {', '.join(episode.meanings)} (0x{episode.bits:02x}) while connecting; "
                          f"{episode.recovery}, cleared by {episode.cleared_by}")


def report_latency_timer(config: HeadConfig, report: Report) -> None:
    """The FTDI adapter's latency timer, where the kernel exposes it, against the servo loop's period."""
    port = config.servo_bus.port
    latency_ms = adapter_latency_timer_ms(port, SYSFS)
    if latency_ms is None:  # no USB-serial adapter behind the port (a pty, the simulated bus), or unplugged
        return
    rate_hz = config.service.servo_rate_hz
    period_ms = 1000.0 / rate_hz
    part = f"adapter latency timer of {port}"
    how = (f"set it to 1 ms with {SERVO_RULES} (it sets ATTR{{device/latency_timer}}=\"1\" for the U2D2, "
           f"0403:6014; put your adapter's idProduct from lsusb there if it is another FTDI chip): sudo cp "
           f"{SERVO_RULES} /etc/udev/rules.d/ && sudo udevadm control --reload && sudo udevadm trigger")
    if latency_ms > LATENCY_SHARE_OF_PERIOD * period_ms:
        report.failed(part, f"{latency_ms:g} ms: every servo reply waits up to that long in the adapter, more than "
                            f"half the {period_ms:g} ms period of the {rate_hz:g} Hz servo loop "
                            f"(service.servo_rate_hz), which cannot keep its rate; {how}")
    elif latency_ms > 1.0:
        report.ok(part, f"{latency_ms:g} ms, within the {rate_hz:g} Hz loop's period; 1 ms shortens every read: {how}")
    else:
        report.ok(part, f"{latency_ms:g} ms")


def report_camera(side: str, camera: Camera, stack: contextlib.ExitStack, timeout_s: float, report: Report) -> None:
    """The camera opened, streamed to a first frame, and its exposure control tried."""
    try:
        stack.enter_context(camera)
        started = time.monotonic()
        camera.enable()
        frame = camera.wait_frame(after_s=started, timeout_s=timeout_s)
    except (DriverError, OSError) as err:
        report.failed(f"camera {side}", str(err))
        return
    h, w = frame.image.shape[:2]
    report.ok(f"camera {side} ({camera.backend_name} {camera.name})",
              f"{w} x {h}, first frame after {time.monotonic() - started:.2f} s, {camera.health.value}")
    report_exposure(side, camera, report)


def report_exposure(side: str, camera: Camera, report: Report) -> None:
    """What the camera does about its exposure, and what it costs where it can do nothing."""
    part = f"camera {side} exposure"
    caps, control = camera.capabilities, camera.config.exposure_control
    if camera.exposure_mode is ExposureMode.MANUAL:
        report.ok(part, f"fixed at {camera.config.exposure_us:g} us (exposure_us)")
    elif control == "lock_per_fixation":
        try:  # what the service does around every fixation, once
            camera.lock_exposure()
            camera.unlock_exposure()
        except (DriverError, OSError) as err:
            report.failed(part, f"holding it failed: {err}")
        else:
            report.ok(part, "held over each fixation (lock and unlock tried)")
    elif caps.simulated and not caps.exposure:
        report.ok(part, "constant (this simulated camera models none)")
    elif caps.exposure_lock:
        report.ok(part, "auto; the camera can hold it: exposure_control: lock_per_fixation keeps the images "
                        "before and after a saccade alike")
    elif caps.exposure:
        report.ok(part, "auto, and the camera cannot hold it: exposure_control: manual with exposure_us fixes it, "
                        "so the images before and after a saccade are alike")
    else:
        report.warn(part, "the camera can neither hold nor fix its exposure: where it adjusts itself, the images "
                          "before and after a saccade differ in brightness, and fewer fixations teach")
