"""The CANopen master: the cell's bus and SYNC, the axis group that runs programs, drive profiles, homing."""
