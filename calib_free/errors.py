"""The one exception hierarchy of `calib_free`."""
from __future__ import annotations


class CalibFreeError(Exception):
    """Root of every error raised by `calib_free`."""


class OutOfRangeError(CalibFreeError, ValueError):
    """An image position outside the image or the disparity range the map covers."""


class MapFileError(CalibFreeError, ValueError):
    """A saved map that cannot be read: missing, corrupt, or made for another grid."""


class CorrespondenceError(CalibFreeError, ValueError):
    """Images that cannot be matched: wrong shapes, a patch larger than the image."""


class DisparityError(CalibFreeError, ValueError):
    """A disparity the pair does not give: no match in the right image scores well enough."""


class TargetPatchError(CalibFreeError, ValueError):
    """An image target a look cannot find again by its patch: flat, repetitive, or beyond the image."""
