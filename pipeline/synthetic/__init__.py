"""Synthetic experiments with exact ground truth: rendered insertion videos with force logs, and
force/angle data with a hidden unmodelled effect from two independently written generator families."""
