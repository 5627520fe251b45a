"""The Dynamixel wire formats, one module per protocol version."""
