"""The benchmarks (make bench): scripts run as `python3 -m bench.<name>` from the repository root,
the Python reference bridge, and tools/ (the C and Rust loads)."""
