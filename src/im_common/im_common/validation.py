"""
The one validation helper of the stack's math modules and the error it raises.

``InvalidParameter`` names the parameter, its value and why it is refused (one line, every error
of a motor, load, plant block or run file). Its home is here, below every math module
(``im_common.params`` and the real plant's blocks import it), so none of them imports another in
a circle.
"""
from __future__ import annotations

import math


def one_line(text) -> str:
    r"""
    Return ``text`` on one line: a name with a line break or another control character escaped.

    Error lines echo what the user wrote (a YAML key "a\nb", ``--set 'k=1\n...'``); the
    command line prints one line per error.
    """
    text = str(text)
    return text if text.isprintable() else repr(text)[1:-1]


class InvalidParameter(ValueError):
    """A parameter value is impossible; the message (one line) names the parameter."""

    def __init__(self, name: str, value, reason: str):
        self.name = name
        self.value = value
        self.reason = reason
        super().__init__(f"invalid parameter '{one_line(name)}' = {value!r}: {one_line(reason)}")


def check_real(name: str, value, lo=None, lo_open: bool = False, allow_none: bool = False):
    """
    Return ``value`` as a finite float (≥ lo, or > lo when ``lo_open``).

    Else InvalidParameter naming ``name``. The one validation helper of the stack's math
    modules.
    """
    if value is None and allow_none:
        return None
    if isinstance(value, bool):
        raise InvalidParameter(name, value, 'must be a real number')
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InvalidParameter(name, value, 'must be a real number') from None
    if not math.isfinite(x):
        raise InvalidParameter(name, value, 'must be finite')
    if lo is not None:
        if lo_open and not x > lo:
            raise InvalidParameter(name, value, f'must be > {lo:g}')
        if not lo_open and not x >= lo:
            raise InvalidParameter(name, value, f'must be >= {lo:g}')
    return x


def check_block(spec, where: str, keys, shape: str = '') -> None:
    """
    Refuse a run-file or motor-file block that is not a mapping of ``keys``.

    One :class:`InvalidParameter` naming ``where`` (not a mapping; ``shape`` describes the one
    expected, default the list of keys) or ``where.key`` (a key it does not know).
    """
    from collections.abc import Mapping
    if not isinstance(spec, Mapping):
        raise InvalidParameter(where, spec, 'must be a mapping' + (
            f': {shape}' if shape else ' of ' + ', '.join(keys)))
    for key in spec:
        if key not in keys:
            raise InvalidParameter(f'{where}.{key}', spec[key],
                                   f"unknown key (known: {', '.join(keys)})")
