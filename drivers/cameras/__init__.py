"""Cameras: the interface and capture thread, their config, stereo pairing, and the OpenCV (V4L2) and Aravis (GenICam) backends."""
