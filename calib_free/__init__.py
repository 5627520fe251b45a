"""The method: a calibration-free gaze map learned online (Karaoguz et al.).

`GazeMap` learns which relative motor command (dpan, dtilt, dverg) brings an image position
(x, y, d) onto both foveae; `calib_free.sim` is a geometric model of the head to learn on.
"""
from calib_free.errors import CalibFreeError, MapFileError, OutOfRangeError
from calib_free.gaze_map import AdaptResult, GazeMap, GazeMapParams

__all__ = ["AdaptResult", "CalibFreeError", "GazeMap", "GazeMapParams", "MapFileError", "OutOfRangeError"]
