"""A bag of fixations of the simulated head, fast: the online experiments' rig (manual clock,
pairs rendered on demand) with the service's tracing controller, each trace written by the
recorder's `FixationWriter` into a `SplitBag`, and what the live run did."""
from __future__ import annotations

import dataclasses
from pathlib import Path

from calib_free.gaze.fixation import FixationRecord
from calib_free.map.adapter import MapAdapter, Sample
from calib_free.map.gaze_map import AdaptResult, GazeMap
from headctl.config.head import HeadConfig, load_config
from headctl.experiments.online import SimulatedHeadRig
from headctl.ros2 import convert
from headctl.ros2.bag import SplitBag
from headctl.ros2.fixation_log import FixationWriter, replay_config
from headctl.ros2.frames import HeadFrames
from headctl.ros2.recorder import bag_topics, cdr
from headctl.service.fixation_trace import FixationTrace, FixationTaps, TracingController


@dataclasses.dataclass
class LiveRun:
    config: HeadConfig
    records: list[FixationRecord]
    adaptations: list[tuple[int, AdaptResult]]  # (fixation index, result), accepted or not


def record_sim_bag(path: Path, fixations: int, seed: int = 0, with_config: bool = True) -> LiveRun:
    """`fixations` exploratory fixations of the simulated head learning from a fresh map,
    recorded into a new bag at `path`."""
    with SimulatedHeadRig(seed=seed, config=load_config()) as rig:
        config = rig.config
        adaptations: list[tuple[int, AdaptResult]] = []

        def on_adapted(sample: Sample, result: AdaptResult) -> None:
            adaptations.append((sample.tag, result))

        taps = FixationTaps()
        traces: list[FixationTrace] = []
        taps.subscribe(traces.append)
        bag = SplitBag(path, bag_topics(config), 512_000_000, 600_000_000_000)
        stamps = convert.Stamps(rig.clock)

        def stamp_ns(monotonic_s: float | None) -> int:
            t = stamps.now() if monotonic_s is None else stamps.of(monotonic_s)
            return int(t.sec) * 1_000_000_000 + int(t.nanosec)

        writer = FixationWriter(lambda name, ns, msg: bag.write(config.ros2.topic(name), ns, cdr(msg)), stamp_ns,
                                HeadFrames(config.ros2).optical)
        if with_config:
            writer.config(replay_config(config))
        records = []
        with MapAdapter(GazeMap(config.map_params(), seed=config.gaze_map.seed), on_adapted=on_adapted) as adapter:
            controller = TracingController(rig.head, adapter, taps, config.fixation.params, seed=seed,
                                           clock=rig.clock.monotonic, learner=adapter)
            for _ in range(fixations):
                records.append(controller.fixate())
                adapter.wait_idle()
                while traces:
                    writer.trace(traces.pop(0))
        bag.close()
    return LiveRun(config, records, adaptations)
