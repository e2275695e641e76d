"""Full-order nonlinear observer of stator currents and rotor fluxes (seed 000 eq. 3.27 / 4.13)."""
