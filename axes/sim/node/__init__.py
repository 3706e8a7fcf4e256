"""A simulated drive's CANopen node: object dictionary, EMCY, NMT, PDOs, heartbeat consumer, the lost master."""
