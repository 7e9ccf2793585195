"""Per-env pieces of ``observer-gym run``: metrics, summary rows and plots (see run.py)."""
