"""Keeping the service alive: the supervisor thread, the restart policy it applies to dead
parts, and systemd's notifications."""
