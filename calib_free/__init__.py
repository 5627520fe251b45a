"""The method: a calibration-free gaze map learned online (Karaoguz et al.).

The map and its learning are in `calib_free.map`, correspondence in `calib_free.correspondence`,
gaze control on the map in `calib_free.gaze`, the geometric head model in `calib_free.sim`.
"""
