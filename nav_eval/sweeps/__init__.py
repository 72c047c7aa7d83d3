"""Robustness sweeps (`segmin robustness`): the closed loop on variants of one field, one parameter at a time."""
