"""Online adaptation of R_r and L_sr/L_r (seed 000 ch. 4)."""
