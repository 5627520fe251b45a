"""Dynamixel control tables: addresses, models, units, one module per servo family."""
