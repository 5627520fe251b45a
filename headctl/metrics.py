"""Prometheus metrics of a running daemon, read from its threads' counters at scrape time.

A custom collector rather than instrumented counters: the servo loop, the fixation thread and
the adapter already count what matters, so a scrape costs nothing between scrapes and the
servo loop never touches a metrics lock. Names follow Prometheus conventions (base units:
seconds, volts; `_total` for counters). README, "The control API", lists them.
"""
from __future__ import annotations

import math
from typing import Any, Iterator

import numpy as np
from prometheus_client import CollectorRegistry
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

AXES = ("pan", "tilt", "vergence")


def _gauge(name: str, doc: str, value: float | None) -> GaugeMetricFamily:
    g = GaugeMetricFamily(name, doc)
    if value is not None and math.isfinite(value):
        g.add_metric([], value)
    return g


class DaemonCollector(Collector):
    def __init__(self, daemon: Any) -> None:
        self.daemon = daemon

    def collect(self) -> Iterator[Metric]:
        d = self.daemon
        up = GaugeMetricFamily("headctl_up", "1 while the daemon runs without a fault, 0.5 degraded, 0 otherwise")
        state = d.state()
        up.add_metric([], {"running": 1.0, "degraded": 0.5}.get(state, 0.0))
        yield up
        faults = d.fault_items()
        yield _gauge("headctl_faults", "faults present now", len(faults))
        yield from self._servo_loop(d.loop)
        yield from self._joints(d.loop)
        yield from self._fixations(d)
        yield from self._learning(d)
        yield from self._cameras(d)
        events = CounterMetricFamily("headctl_events", "events published to clients, by type", labels=["type"])
        for type_, count in sorted(d.hub.counts.items()):
            events.add_metric([type_], count)
        yield events
        yield _gauge("headctl_looks_queued", "looks waiting for the fixation thread", d.looks.pending())

    def _servo_loop(self, loop: Any) -> Iterator[Metric]:
        if loop is None:
            return
        yield CounterMetricFamily("headctl_servo_loop_cycles", "servo loop cycles", loop.cycles)
        yield CounterMetricFamily("headctl_servo_loop_overruns", "cycles that overran their period", loop.overruns)
        timing = loop.timing()
        for name, what in (("period", "servo loop period"), ("jitter", "|period - nominal|")):
            family = GaugeMetricFamily(f"headctl_servo_loop_{name}_seconds",
                                       f"{what} over the last 6,000 cycles, by quantile", labels=["quantile"])
            for q, label in (("0.5", "p50"), ("0.99", "p99"), ("1.0", "max")):
                value = timing[f"{name}_{label}_ms"]
                if value is not None:
                    family.add_metric([q], value / 1e3)
            yield family
        errors = CounterMetricFamily("headctl_servo_bus_errors", "servo bus errors, by kind", labels=["kind"])
        errors.add_metric(["read"], loop.read_errors)
        errors.add_metric(["write"], loop.write_errors)
        errors.add_metric(["down"], loop.bus_down_count)
        yield errors
        yield _gauge("headctl_servo_bus_down", "1 while the servo bus is down", float(loop.down_reason is not None))
        yield _gauge("headctl_torque_enabled", "1 while torque is on (as switched)", float(loop.torque_enabled))

    def _joints(self, loop: Any) -> Iterator[Metric]:
        state = loop.latest_state() if loop is not None else None
        families = {
            "position": GaugeMetricFamily("headctl_joint_position_degrees", "joint angle", labels=["joint"]),
            "temperature": GaugeMetricFamily("headctl_servo_temperature_celsius", "servo temperature",
                                             labels=["joint"]),
            "voltage": GaugeMetricFamily("headctl_servo_input_voltage_volts", "servo input voltage",
                                         labels=["joint"]),
            "error": GaugeMetricFamily("headctl_servo_hardware_error", "1 while the servo reports a hardware error",
                                       labels=["joint"]),
        }
        if state is not None:
            for joint, js in state.joints.items():
                families["position"].add_metric([joint], js.position)
                families["temperature"].add_metric([joint], js.temperature_c)
                families["voltage"].add_metric([joint], js.input_voltage_v)
                families["error"].add_metric([joint], float(bool(js.hardware_error_bits)))
        yield from families.values()

    def _fixations(self, d: Any) -> Iterator[Metric]:
        fix = d.fixation
        counts = fix.counts() if fix is not None else {"done": 0, "taught": 0, "refused": {}}
        yield CounterMetricFamily("headctl_fixations", "fixations done (taught or refused)", counts["done"])
        yield CounterMetricFamily("headctl_fixations_taught", "fixations that taught the map", counts["taught"])
        refused = CounterMetricFamily("headctl_fixations_refused", "fixations that did not teach, by reason",
                                      labels=["reason"])
        for reason, count in sorted(counts["refused"].items()):
            refused.add_metric([reason], count)
        yield refused
        yield _gauge("headctl_exploration_enabled", "1 while exploratory fixations run",
                     float(bool(fix.explore)) if fix is not None else None)

    def _learning(self, d: Any) -> Iterator[Metric]:
        adapter = d.adapter
        if adapter is not None:
            yield CounterMetricFamily("headctl_adaptations", "adaptations of the gaze map (this map)",
                                      adapter.progress.adaptations)
        points = d.learning_since(0, 100)["points"]
        retinal = [p["retinal_error"] for p in points if p["retinal_error"] is not None]
        confidence = [p["confidence"] for p in points if p["confidence"] is not None]
        yield _gauge("headctl_retinal_error_ratio", "mean retinal error (eq. 8) of the last 100 adaptations, "
                     "a fraction of the half-ranges", float(np.mean(retinal)) if retinal else None)
        yield _gauge("headctl_confidence_ratio", "mean confidence (eq. 7) of the last 100 taught fixations",
                     float(np.mean(confidence)) if confidence else None)
        output = GaugeMetricFamily("headctl_output_error_degrees",
                                   "mean |correction| of the last 100 adaptations, by axis", labels=["axis"])
        errors = [p["output_error_deg"] for p in points if p["output_error_deg"] is not None]
        if errors:
            for axis, value in zip(AXES, np.nanmean(np.asarray(errors, dtype=float), axis=0)):
                if math.isfinite(value):
                    output.add_metric([axis], float(value))
        yield output
        landing = list(d.fixation.landing_errors_px) if d.fixation is not None else []
        yield _gauge("headctl_landing_error_pixels", "median landing error of the last target looks (what the "
                     "head fixated vs the target, in the image before the saccade)",
                     float(np.median(landing)) if landing else None)

    def _cameras(self, d: Any) -> Iterator[Metric]:
        frames = CounterMetricFamily("headctl_camera_frames", "frames delivered, by camera", labels=["camera"])
        errors = CounterMetricFamily("headctl_camera_errors", "camera errors, by camera", labels=["camera"])
        for side, camera in d.cameras.items():
            stats = camera.stats()
            frames.add_metric([side], stats.get("frames", 0))
            errors.add_metric([side], stats.get("errors", 0))
        yield frames
        yield errors


def registry_for(daemon: Any) -> CollectorRegistry:
    """A registry of its own (not the process-global one): several daemons in one test process."""
    registry = CollectorRegistry()
    registry.register(DaemonCollector(daemon))
    return registry
