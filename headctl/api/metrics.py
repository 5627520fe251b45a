"""Prometheus metrics of a running service, read from one status snapshot at scrape time.

A custom collector rather than instrumented counters: the servo loop, the fixation thread and
the adapter already count what matters, so a scrape costs nothing between scrapes and the
servo loop never touches a metrics lock. Names follow Prometheus conventions (base units:
seconds, volts; `_total` for counters). docs/api.md lists them.
"""
from __future__ import annotations

import math
from typing import Iterator

from prometheus_client import CollectorRegistry
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from calib_free.kinematics import AXES
from headctl.service.control import HeadService
from headctl.service.parts import ServicePhase
from headctl.service.status import StatusSnapshot


def _gauge(name: str, doc: str, value: float | None) -> GaugeMetricFamily:
    g = GaugeMetricFamily(name, doc)
    if value is not None and math.isfinite(value):
        g.add_metric([], value)
    return g


class ServiceCollector(Collector):
    """The metrics of one status snapshot, taken at scrape time."""

    def __init__(self, service: HeadService) -> None:
        self.service = service

    def collect(self) -> Iterator[Metric]:
        snap = self.service.snapshot()
        up = GaugeMetricFamily("headctl_up", "1 while the daemon runs without a fault, 0.5 degraded, 0 otherwise")
        up.add_metric([], {ServicePhase.RUNNING: 1.0, ServicePhase.DEGRADED: 0.5}.get(snap.state, 0.0))
        yield up
        yield _gauge("headctl_faults", "faults present now", len(snap.faults))
        yield from self._servo_loop(snap)
        yield from self._joints(snap)
        yield from self._fixations(snap)
        yield from self._learning(snap)
        yield from self._cameras(snap)
        events = CounterMetricFamily("headctl_events", "events published to clients, by type", labels=["type"])
        for type_, count in sorted(snap.event_counts.items()):
            events.add_metric([type_], count)
        yield events
        yield _gauge("headctl_looks_queued", "looks waiting for the fixation thread", snap.fixation.looks_queued)

    def _servo_loop(self, snap: StatusSnapshot) -> Iterator[Metric]:
        timing = snap.servo_loop
        if timing is None:
            return
        yield CounterMetricFamily("headctl_servo_loop_cycles", "servo loop cycles", timing["cycles"])
        yield CounterMetricFamily("headctl_servo_loop_overruns", "cycles that overran their period",
                                  timing["overruns"])
        yield CounterMetricFamily("headctl_servo_loop_long_periods", "periods over 1.2 times the nominal one "
                                  "(12 ms at 100 Hz)", timing.get("long_periods", 0))
        for name, what in (("period", "servo loop period"), ("jitter", "|period - nominal|")):
            family = GaugeMetricFamily(f"headctl_servo_loop_{name}_seconds",
                                       f"{what} over the last 6,000 cycles, by quantile", labels=["quantile"])
            for q, label in (("0.5", "p50"), ("0.99", "p99"), ("1.0", "max")):
                value = timing[f"{name}_{label}_ms"]
                if value is not None:
                    family.add_metric([q], value / 1e3)
            yield family
        errors = CounterMetricFamily("headctl_servo_bus_errors", "servo bus errors, by kind", labels=["kind"])
        errors.add_metric(["read"], timing["read_errors"])
        errors.add_metric(["write"], timing["write_errors"])
        errors.add_metric(["down"], timing["bus_down_count"])
        yield errors
        reboots = CounterMetricFamily("headctl_servo_reboots", "automatic reboots of a servo after a hardware "
                                      "error, by joint and reason", labels=["joint", "reason"])
        for entry in snap.hardware_errors["reboots"]:
            reboots.add_metric([entry["joint"], entry["reason"]], entry["count"])
        yield reboots
        yield CounterMetricFamily("headctl_servo_process_restarts", "servo processes that died and were replaced",
                                  snap.restarts.get("servo-io", 0))
        restarts = CounterMetricFamily("headctl_restarts", "parts of the service restarted after they died, "
                                       "by part", labels=["part"])
        for part, count in sorted(snap.restarts.items()):
            restarts.add_metric([part], count)
        yield restarts
        yield _gauge("headctl_servo_hardware_errors_open", "hardware-error episodes open now",
                     len(snap.hardware_errors["open"]))
        yield _gauge("headctl_servo_bus_down", "1 while the servo bus is down", float(snap.bus_down))
        yield _gauge("headctl_torque_enabled", "1 while torque is on (as switched)",
                     None if snap.torque is None else float(snap.torque))

    def _joints(self, snap: StatusSnapshot) -> Iterator[Metric]:
        families = {
            "position": GaugeMetricFamily("headctl_joint_position_degrees", "joint angle", labels=["joint"]),
            "temperature": GaugeMetricFamily("headctl_servo_temperature_celsius", "servo temperature",
                                             labels=["joint"]),
            "voltage": GaugeMetricFamily("headctl_servo_input_voltage_volts", "servo input voltage",
                                         labels=["joint"]),
            "error": GaugeMetricFamily("headctl_servo_hardware_error", "1 while the servo reports a hardware error",
                                       labels=["joint"]),
        }
        for joint, js in snap.joints.items():
            families["position"].add_metric([joint], js.position_deg)
            families["temperature"].add_metric([joint], js.temperature_c)
            families["voltage"].add_metric([joint], js.input_voltage_v)
            families["error"].add_metric([joint], float(bool(js.hardware_errors)))
        yield from families.values()

    def _fixations(self, snap: StatusSnapshot) -> Iterator[Metric]:
        fix = snap.fixation
        yield CounterMetricFamily("headctl_fixations", "fixations done (taught or refused)", fix.done)
        yield CounterMetricFamily("headctl_fixations_taught", "fixations that taught the map", fix.taught)
        refused = CounterMetricFamily("headctl_fixations_refused", "fixations that did not teach, by reason",
                                      labels=["reason"])
        for reason, count in sorted(fix.refused.items()):
            refused.add_metric([reason], count)
        yield refused
        yield _gauge("headctl_exploration_enabled", "1 while exploratory fixations run", float(fix.explore))

    def _learning(self, snap: StatusSnapshot) -> Iterator[Metric]:
        learning = snap.learning
        if learning is not None:
            yield CounterMetricFamily("headctl_adaptations", "adaptations of the gaze map (this map)",
                                      learning.adaptations)
        yield _gauge("headctl_retinal_error_ratio", "mean retinal error (eq. 8) of the last 100 adaptations, "
                     "a fraction of the half-ranges", learning.recent_mean_retinal_error if learning else None)
        yield _gauge("headctl_confidence_ratio", "mean confidence (eq. 7) of the last 100 taught fixations",
                     learning.recent_mean_confidence if learning else None)
        output = GaugeMetricFamily("headctl_output_error_degrees",
                                   "mean |correction| of the last 100 adaptations, by axis", labels=["axis"])
        for axis, value in zip(AXES, (learning.recent_mean_output_error_deg or []) if learning else []):
            if math.isfinite(value):
                output.add_metric([axis], float(value))
        yield output
        yield _gauge("headctl_landing_error_pixels", "median landing error of the last target looks (what the "
                     "head fixated vs the target, in the image before the saccade)",
                     snap.fixation.landing_error_px_median)

    def _cameras(self, snap: StatusSnapshot) -> Iterator[Metric]:
        frames = CounterMetricFamily("headctl_camera_frames", "frames delivered, by camera", labels=["camera"])
        errors = CounterMetricFamily("headctl_camera_errors", "camera errors, by camera", labels=["camera"])
        for side, camera in snap.cameras.items():
            frames.add_metric([side], camera.stats.get("frames", 0))
            errors.add_metric([side], camera.stats.get("errors", 0))
        yield frames
        yield errors


def registry_for(service: HeadService) -> CollectorRegistry:
    """A registry of its own (not the process-global one): several services in one test process."""
    registry = CollectorRegistry()
    registry.register(ServiceCollector(service))
    return registry
