"""A simulated drive's CANopen node: object dictionary, NMT, PDOs, heartbeat consumer."""
