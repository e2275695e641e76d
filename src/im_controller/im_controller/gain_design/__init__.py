"""
Gain design for the drive's fixed-rate loops (current loop and observer injection).

Drive-specific use of the generic synthesis library :mod:`im_robust` (seed 001) on the models of
seed 000: :mod:`.motor` (sampled 4-state models, 4-state designs, the thesis gain's sampled-data
limit) and :mod:`.drive` (the gains the nodes use, designed at the node period). It lives next to
the loops it designs because it needs the observer's one-period error map; ``im_robust`` itself
imports no drive package (docs/architecture.md).
"""
