"""The cyclic path on the wall clock (SYNC, time stamp, setpoints, records, quick stop) in a process of its own."""
