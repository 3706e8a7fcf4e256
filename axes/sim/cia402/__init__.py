"""A simulated drive's CiA 402 device: power states, faults, homing, its motion segments and samples."""
