"""The simulated drive behaviours: EPOS2 buffered PVT, linear IP, one setpoint per SYNC, Parker."""
