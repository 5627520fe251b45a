"""The servo I/O: the servo loop (a thread or a process of its own), its shared-memory state block,
the messages between the service and that process, and the servos' hardware faults."""
