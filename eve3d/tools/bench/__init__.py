"""``eve3d bench``: speed, memory and accuracy benchmarks that print a table (never timed
tests), one module per what it measures."""
