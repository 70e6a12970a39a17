"""canbench: the CAN <-> Zenoh bridge test bench (scenarios, capture, oracle, reports)."""

__version__ = "0.1.0"
