"""The servo bus: the generic interface (joints, states, limits), its config, fault records, recovery policy and the servo probe."""
