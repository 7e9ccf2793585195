"""mylab: an observer and a controller for observer-gym's BallTable-v0, written outside
the package (docs/your_method.md)."""

__version__ = "0.1.0"
