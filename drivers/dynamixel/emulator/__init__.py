"""A Dynamixel servo emulator on a pseudo-terminal: the server, one module per protocol's instructions, the emulated servos, fault injection."""
