"""Developer tools: ``eve3d bench`` (benchmarks that print a table), the stand-ins for
benchmark downloads, and the generator of config/README.md's key tables."""
