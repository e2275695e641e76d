"""
The computational delay of a digital drive: the command computed at step k acts over step k + d.

A DSP samples the currents at t_k, computes the voltage from them and loads it into the PWM for
the next period: the command V_k acts over [t_{k+1}, t_{k+2}] (d = 1; motulator's plant has it by
default). The run file's ``inverter: {delay: d}`` (docs/plant.md §10) puts one
:class:`CommandDelay` in the plant, between the command's checks and the inverter, and one in
each part of the drive that integrates the voltage the motor received (the observer, the adapter,
the ROS-free loop's books): all of them hold the same line of commands, so the drive's models see
the voltage the plant applies, step for step.

Before the first command has gone through, the line holds the first command itself: the drive's
first voltage acts from t_0, the next ones d periods late. A drive started in its steady state
(``start: steady``) was commanding about that voltage already, so it starts without a kick; one at
rest starts its magnetization at once (a DSP's first period would hold the zero vector: the same
start, d periods later).

The line can also be fed and read apart (:meth:`CommandDelay.enter`, :meth:`CommandDelay.take`):
the plant node enters each command when it comes and integrates a step as soon as the command
acting over it is in the line, d steps before the command of that step has come (the delayed
step overlapped, docs/architecture.md).
"""
from __future__ import annotations

from collections import deque
from typing import Tuple

from .validation import InvalidParameter

#: the longest delay accepted [control periods]: 1 is a DSP's (double update), 2 single update
#: with the duties loaded at the next sample
MAX_DELAY = 2
Command = Tuple[float, float]


def check_delay(value, name: str = 'delay') -> int:
    """Return ``value`` as a delay in control periods (0..MAX_DELAY), else one error line."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_DELAY:
        raise InvalidParameter(name, value, f'must be a whole number of control periods, 0 to '
                                            f'{MAX_DELAY}')
    return value


class CommandDelay:
    """
    A line of ``d`` commands: :meth:`push` gives the command of step k, returns that of k − d.

    Before the first push the line is empty; the first command fills it (module doc). d = 0
    returns each command as it comes.
    """

    def __init__(self, d: int = 0):
        self.d = check_delay(d)
        self._line: deque = deque()
        self._started = False       # the first command has entered (and filled the line)

    def push(self, v_a: float, v_b: float) -> Command:
        """Enter the command of this step; return the one that acts over it (k − d)."""
        if not self.d:
            return v_a, v_b
        self.enter(v_a, v_b)
        return self._line.popleft()

    def enter(self, v_a: float, v_b: float) -> None:
        """
        Enter the next command without taking one: the line then holds one more acting command.

        With :meth:`take`, the overlapped order of a delayed step (:attr:`ready`): the command of
        step j enters when it comes, the one acting over step k is taken when step k is
        integrated, which needs only the command of step k − d. ``push`` is ``enter`` then
        ``take``.
        """
        if not self._started:
            self._started = True
            self._line.extend([(v_a, v_b)] * self.d)
        self._line.append((v_a, v_b))

    def take(self) -> Command:
        """Return the command that acts over the next step (IndexError if none has entered)."""
        return self._line.popleft()

    @property
    def ready(self) -> int:
        """Return how many steps the commands entered so far can act over (after d: d + 1)."""
        return len(self._line)

    def pending(self) -> Tuple[Command, ...]:
        """Return the commands given but not yet acting, oldest first (empty before the first)."""
        return tuple(self._line)
