"""Baseline controllers (to come): LQR, MPC, PID, visual tracking, intercept."""
