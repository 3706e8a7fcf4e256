"""The drive's facts: CiA 402 and the vendors' objects, interpolation, PVT programs, scaling, the cell's wiring."""
