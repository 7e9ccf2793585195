"""Robots shared by the environments; each receives the Simulation it lives in."""
