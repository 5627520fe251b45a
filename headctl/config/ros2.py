"""The config's `ros2:` section: the service on ROS 2 topics over DDS (`headctl.ros2`).

Off by default. `domain_id` and `namespace` place the node as `ROS_DOMAIN_ID` and a node's
namespace would; `distro` picks the `ros_discovery_info` layout the ROS 2 tools of that
release expect (its Gid is 24 bytes in Humble, 16 from Iron on); `localhost_only` keeps the
participant to the loopback interface (as `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`);
`commands` opens the command topics, which plain DDS lets anyone on the network publish to.
`mechanics` is the head's nominal geometry, from which the frames on `/tf` and `/tf_static`
are made (the learned map needs none of it); its defaults are the simulated head's.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

from drivers.config.reader import check_settings, setting

DISTROS = ("humble", "jazzy", "kilted")
RELIABILITIES = ("best_effort", "reliable")
# A ROS 2 namespace: empty, or /-separated tokens of letters, digits and _ (not starting with a digit).
_NAMESPACE = re.compile(r"(/[A-Za-z_][A-Za-z0-9_]*)*")
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_FRAME = re.compile(r"[A-Za-z_][A-Za-z0-9_/]*")


def _finite_vector(v: tuple[float, float, float]) -> bool:
    return all(-10.0 <= x <= 10.0 for x in v)


@dataclass(frozen=True)
class Ros2Rates:
    """`ros2.rates`: how often each stream is published."""

    # None: the servo loop's rate (service.servo_rate_hz)
    joint_states_hz: float | None = setting(None, above=0.0, hi=1000.0, expected="a rate in (0, 1000] Hz")
    # None: every new frame (the camera's rate)
    images_fps: float | None = setting(None, above=0.0, hi=240.0, expected="a rate in (0, 240] frames a second")
    diagnostics_hz: float = setting(1.0, above=0.0, hi=100.0, expected="a rate in (0, 100] Hz")

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class Ros2Qos:
    """`ros2.qos`: the depths and the images' reliability (ROS 2's profiles by default)."""

    # sensor data: best effort, keep last 5 (rclcpp::SensorDataQoS)
    images: str = setting("best_effort", choices=RELIABILITIES, expected=" or ".join(RELIABILITIES))
    images_depth: int = setting(5, lo=1, hi=1000, expected="1 to 1000")
    # reliable, volatile, keep last (the default profile's 10)
    depth: int = setting(10, lo=1, hi=1000, expected="1 to 1000")
    # /tf: tf2_ros's TransformBroadcaster keeps 100
    tf_depth: int = setting(100, lo=1, hi=10000, expected="1 to 10000")

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class Ros2Images:
    """`ros2.images`: which image topics are published."""

    raw: bool = True  # image_raw (sensor_msgs/Image)
    compressed: bool = True  # image_raw/compressed (JPEG)
    jpeg_quality: int = setting(80, lo=10, hi=100, expected="10 to 100")

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class Ros2Mechanics:
    """`ros2.mechanics`: the head's nominal geometry (metres), the frames' transforms.

    base -> neck pan (about z) -> neck tilt (about -y, + raises the head) -> each eye (about
    -z, + toward the head's right) -> each camera's optical frame (z forward, x right, y down).
    """

    # from the base frame to the pan axis
    pan_origin_m: tuple[float, float, float] = setting((0.0, 0.0, 0.0), check=_finite_vector,
                                                       expected="[x, y, z] in metres, each within +-10")
    # from the pan axis to the tilt axis (in the panned frame)
    tilt_origin_m: tuple[float, float, float] = setting((0.0, 0.0, 0.0), check=_finite_vector,
                                                        expected="[x, y, z] in metres, each within +-10")
    # between the eyes' axes
    baseline_m: float = setting(0.060, above=0.0, hi=2.0, expected="a length in (0, 2] m")
    # each eye's axis from the tilt axis: forward, up
    eye_offset_m: tuple[float, float] = setting((0.02, 0.06), check=lambda v: all(-10.0 <= x <= 10.0 for x in v),
                                                expected="[forward, up] in metres, each within +-10")

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class Ros2Recording:
    """`ros2.recording`: the rosbag2 bags `headctl record` writes (headctl.ros2.recorder); they
    need no DDS, so they work with `ros2.enabled` false."""

    # where bags go ('' : <state_dir>/recordings); a request may name another directory
    directory: str = ""
    # a bag's files are split at this size or this duration, whichever comes first
    max_bag_size_mb: float = setting(512.0, above=0.0, hi=1e6, expected="a size in (0, 1e6] MB")
    max_bag_duration_s: float = setting(600.0, above=0.0, hi=86400.0, expected="a duration in (0, 86400] s")
    # the longest recording a request may ask for ('headctl record --seconds')
    max_seconds: float = setting(86400.0, above=0.0, hi=1e7, expected="a duration in (0, 1e7] s")

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class Ros2Config:
    """The `ros2:` section (docs/ros2.md, docs/config.md)."""

    enabled: bool = False
    domain_id: int = setting(0, lo=0, hi=232, expected="a DDS domain id, 0 to 232 (ROS_DOMAIN_ID)")
    namespace: str = setting("", check=lambda n: bool(_NAMESPACE.fullmatch(n)),
                             expected="'' or a ROS 2 namespace such as /head1 (/-separated names of letters, "
                                      "digits and _)")
    node_name: str = setting("headctl", check=lambda n: bool(_NAME.fullmatch(n)),
                             expected="a ROS 2 node name (letters, digits and _, not starting with a digit)")
    distro: str = setting("jazzy", choices=DISTROS, expected=" or ".join(DISTROS))
    # only the loopback interface, no multicast (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST)
    localhost_only: bool = False
    # accept /head/look_at, /head/look_at_angles, /head/track (anyone on the DDS network can publish)
    commands: bool = False
    # prefixed to every frame id and joint name ('' or e.g. 'head1/')
    frame_prefix: str = setting("", check=lambda p: p == "" or bool(_FRAME.fullmatch(p)),
                                expected="'' or a prefix of letters, digits, _ and /")
    base_frame: str = setting("base_link", check=lambda f: bool(_FRAME.fullmatch(f)),
                              expected="a frame id (letters, digits, _ and /)")
    rates: Ros2Rates = field(default_factory=Ros2Rates)
    qos: Ros2Qos = field(default_factory=Ros2Qos)
    images: Ros2Images = field(default_factory=Ros2Images)
    mechanics: Ros2Mechanics = field(default_factory=Ros2Mechanics)
    recording: Ros2Recording = field(default_factory=Ros2Recording)

    def __post_init__(self) -> None:
        check_settings(self)

    def topic(self, name: str) -> str:
        """The ROS 2 name of a topic (`joint_states` -> `/joint_states`, under the namespace)."""
        return f"{self.namespace}/{name}"
