"""Missing-physics discovery: locate the mismatch, rank candidate effects, re-identify, report."""
