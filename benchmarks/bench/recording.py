"""Recording throughput: what a bag of the simulated head costs, and how fast a bag takes data.

1. The service in this process (simulated head, 320 x 240, two eyes, 30 fps, servo loop at
   its rate) records for `--seconds` (`headctl.ros2.recorder.Recordings`): messages a second
   by topic, the bag's megabytes a second, and the recording thread's CPU as a share of one
   core (its `time.thread_time()`: the JPEG encoding, serialisation and writes).
2. `SplitBag` alone: 320 x 240 JPEG `CompressedImage`s written as fast as it takes them, with
   a split every 64 MB: messages and megabytes a second to the disk of `--dir`.

    .venv/bin/python -m benchmarks.bench.recording [--seconds 10] [--dir /tmp]
"""
from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from headctl.api.compose import serve
from headctl.config.head import load_config
from headctl.config.ros2 import Ros2Config, Ros2Recording
from headctl.ros2 import convert
from headctl.ros2.bag import BagTopic, SplitBag
from headctl.ros2.recorder import Recordings, cdr


def service_recording(seconds: float, directory: Path) -> None:
    config = load_config().with_state_dir(directory / "state").with_api(port=0)
    config = dataclasses.replace(config, ros2=Ros2Config(recording=Ros2Recording(directory=str(directory))))
    with serve(config) as daemon:
        deadline = time.monotonic() + 30
        while daemon.control.latest_frame("left") is None and time.monotonic() < deadline:
            time.sleep(0.05)
        with Recordings(daemon.control, config) as recordings:
            recordings.start(seconds=seconds)
            assert recordings.current is not None
            recordings.current.join(seconds + 30)
            status = recordings.status()
    path = Path(str(status["path"]))
    size_mb = sum(p.stat().st_size for p in path.glob("*.mcap")) / 1e6
    duration = float(status["duration_s"])  # type: ignore[arg-type]
    print(f"service recording: {duration:.1f} s, state {status['state']}, {size_mb:.1f} MB "
          f"({size_mb / duration:.2f} MB/s), recorder CPU {100 * float(status['cpu_s']) / duration:.1f} % of a core")
    messages = status["messages"]
    assert isinstance(messages, dict)
    for topic, count in sorted(messages.items()):
        print(f"  {topic:36s} {int(count) / duration:7.1f} /s")  # type: ignore[call-overload]


def bag_throughput(seconds: float, directory: Path) -> None:
    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur(rng.integers(0, 255, (240, 320, 3), dtype=np.uint8), (5, 5), 0)
    ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 80])
    assert ok
    msg = convert.m.CompressedImage(header=convert.m.Header(stamp=convert.m.Time.of_seconds(time.time()),
                                                            frame_id="left_camera_optical_frame"),
                                    format="bgr8; jpeg compressed bgr8", data=jpeg.tobytes())
    data = cdr(msg)
    bag = SplitBag(directory / "throughput", [BagTopic("/head/left/image_raw/compressed",
                                                       "sensor_msgs/msg/CompressedImage")],
                   max_bytes=64_000_000, max_duration_ns=10**15)
    n, t0 = 0, time.perf_counter()
    stamp_ns = time.time_ns()
    while time.perf_counter() - t0 < seconds:
        for _ in range(100):
            bag.write("/head/left/image_raw/compressed", stamp_ns + n * 33_000_000, data)
            n += 1
    bag.close()
    elapsed = time.perf_counter() - t0
    print(f"SplitBag alone: {n / elapsed:.0f} messages/s of {len(data) / 1e3:.1f} kB, "
          f"{n * len(data) / elapsed / 1e6:.0f} MB/s, {len(bag.files)} files")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--dir", type=Path, default=None, help="where the bags go (default: a temporary directory)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        service_recording(args.seconds, Path(tmp))
        bag_throughput(min(args.seconds, 5.0), Path(tmp))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
