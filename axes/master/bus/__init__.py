"""The cell's bus: the network, SYNC and its followers, heartbeats, bus state, the quick stop."""
