"""Simulated induction motor, load and inverter; owns simulated time."""
