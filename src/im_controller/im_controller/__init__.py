"""Torque-tracking controller with minimum magnetic energy (seed 000 ch. 3-4)."""
