"""The axis group: configure, start on one SYNC, feed, halt and recover a cell's drives."""
