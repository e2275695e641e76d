"""
The thesis's published reference figures: the one home of every number the tools compare with.

Seed 000 §3.4.7 (Table of energies): energy drawn from the source and losses, in J, per task and
flux strategy, with the thesis's motor, loads, gains and T_s = 100 µs. The study, ``make '
                        thesis'reproduce``'
and the README's generated results block all read them from here.
"""
from __future__ import annotations

from typing import Dict, Optional, Tuple

#: (task, strategy) -> (E_in [J], losses [J]), seed 000 §3.4.7
ENERGY: Dict[Tuple[str, str], Tuple[float, float]] = {
    ('position', 'min_energy'): (146.78, 128.25),
    ('position', 'constant_flux'): (340.15, 313.78),
    ('speed', 'min_energy'): (587.69, 56.31),
    ('speed', 'constant_flux'): (1078.8, 528.57),
}


def energy(task: str, strategy: str) -> Optional[Tuple[float, float]]:
    """(E_in, losses) the thesis prints for this run, or None where it prints none (min_loss)."""
    return ENERGY.get((task, strategy))


def losses(task: str, strategy: str) -> float:
    """Return the thesis's losses [J] for a run it reports; KeyError names the run otherwise."""
    try:
        return ENERGY[(task, strategy)][1]
    except KeyError:
        raise KeyError(f'the thesis prints no losses for task={task!r} '
                       f'strategy={strategy!r}') from None
