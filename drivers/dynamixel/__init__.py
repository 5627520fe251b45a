"""Dynamixel servos: the Protocol 2.0 and 1.0 buses over dynamixel-sdk, their wire formats, control tables, scan, probe and emulator."""
