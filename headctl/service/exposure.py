"""The cameras' exposure held over a fixation (`exposure_control: lock_per_fixation`).

A fixation teaches from the pair taken before its saccade and the pair taken once it has
converged: correspondence finds in the first what is on the foveae in the second, and its
confidence falls with every difference between the two that is not the motion. A camera's
auto exposure and gain that follow the new view between them change the brightness, so
fewer fixations pass and teach. `ExposureHold.held()` locks both cameras' exposure before
the fixation's first image and unlocks it after the fixation ends, however it ends; between
fixations the auto exposure follows the room's light again.

Used around each exploratory fixation and around a client's whole look (its corrective
fixations find the target of the look's first image again) on the fixation thread, and
around each fixation of the online experiments. Not around a track: pursuit matches its
patch by normalised cross-correlation from one pair to the next (insensitive to a uniform
change of brightness) and takes its template again as the target changes, it teaches no
sample, and a track lasts as long as a client wants, longer than one exposure can suit
the light the target moves through.

A camera that cannot be locked (lost, reconnecting) is logged and the fixation goes on: one
without frames ends refused on its own, one with them only teaches less.
"""
from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterable, Iterator

from drivers.cameras.camera import Camera
from drivers.errors import CameraError, DeviceStateError

log = logging.getLogger(__name__)


class ExposureHold:
    """Locks the exposure of the cameras configured `lock_per_fixation`, for a block."""

    def __init__(self, cameras: Iterable[Camera] = ()) -> None:
        self.cameras = tuple(c for c in cameras if c.config.exposure_control == "lock_per_fixation")
        self.holds = 0  # blocks run with every such camera locked
        self.failures = 0  # locks and unlocks that failed

    @contextlib.contextmanager
    def held(self) -> Iterator[None]:
        """Run the block with the cameras' exposure locked; unlocked afterwards, always."""
        locked: list[Camera] = []
        try:
            for camera in self.cameras:
                try:
                    camera.lock_exposure()
                except (CameraError, DeviceStateError) as err:
                    self.failures += 1
                    log.warning("%s: exposure not held for this fixation: %s", camera.name, err)
                else:
                    locked.append(camera)
            if locked and len(locked) == len(self.cameras):
                self.holds += 1
            yield
        finally:
            for camera in locked:
                try:
                    camera.unlock_exposure()
                except (CameraError, DeviceStateError) as err:  # tried again after the next fixation
                    self.failures += 1
                    log.warning("%s: exposure still held after the fixation: %s", camera.name, err)
