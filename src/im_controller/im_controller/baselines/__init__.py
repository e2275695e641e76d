"""
The drive industry's controllers beside the thesis's law (issue 43, the first baselines).

The laws here are what a drive maker ships, written from their published designs
(motulator 0.18's, read as math): the current-vector controller (:mod:`.current_vector`: a
sensored reduced-order flux observer, a 2DOF complex-vector PI current controller in estimated
rotor-flux coordinates and a 2DOF speed PI) with its gains (:mod:`.gains`, the ``baseline:``
block). They run beside the thesis's law so the two can be compared on the same plant, with the
same computational delay.

Everything here is ROS-free pure Python, one call per control period, in the stack's
**power-invariant** units (torque τ = n_p Im(i_s ψ_s*), no factor 3/2) and the inverse-Γ
parameters of :class:`im_common.params.MotorParams` (L_σ, L_M, R_R; ψ_R = θ φ_r). The derivations
and the comparison are to be written in docs/baselines.md (future).
"""
