"""
The one validation helper of the stack's math modules and the error it raises.

``InvalidParameter`` names the parameter, its value and why it is refused (one line, every error
of a motor, load, plant block or run file). Its home is here, below every math module
(``im_common.params`` and the real plant's blocks import it), so none of them imports another in
a circle. :func:`parse_block` turns a run-file block's pydantic model (the inverter's, the
sensors') and its errors into the same lines.
"""
from __future__ import annotations

from collections.abc import Mapping
import math
from typing import get_args, get_origin, Literal

from pydantic import ValidationError


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
    if not isinstance(spec, Mapping):
        raise InvalidParameter(where, spec, 'must be a mapping' + (
            f': {shape}' if shape else ' of ' + ', '.join(keys)))
    for key in spec:
        if key not in keys:
            raise InvalidParameter(f'{where}.{key}', spec[key],
                                   f"unknown key (known: {', '.join(keys)})")


#: the ``model_config`` of a run-file block's pydantic model (a ConfigDict, as a plain dict:
#: this module imports no pydantic until a block is parsed): frozen, no key it does not know, a
#: bool or a string is no number, a number is finite
BLOCK_CONFIG = {'frozen': True, 'extra': 'forbid', 'strict': True, 'allow_inf_nan': False}
#: pydantic's bound errors and the comparison each one states
_BOUNDS = {'greater_than': ('gt', '>'), 'greater_than_equal': ('ge', '>='),
           'less_than': ('lt', '<'), 'less_than_equal': ('le', '<=')}
#: pydantic's type errors and the line each one gives
_TYPES = {'float_type': 'must be a real number', 'int_type': 'must be a whole number',
          'bool_type': 'must be true or false', 'string_type': 'must be a string',
          'finite_number': 'must be finite'}


def parameter_spec(default=None, lo=None, hi=None, sentinels=()):
    """
    Return a model field's ``json_schema_extra``: the node parameter of that field.

    ``default``: the parameter's default when it is not the field's (a sentinel); ``lo``, ``hi``:
    the parameter's range; ``sentinels``: (parameter value, the field value it stands for, what
    it means) — the one place a -1 / 0 / [0.0] of a node parameter is given its meaning
    (:func:`im_common.node_params.declare_model`, :func:`im_common.node_params.declare_block`,
    :func:`im_common.node_params.model_arguments`).
    """
    spec = {'range': (lo, hi), 'sentinels': tuple(sentinels)}
    if default is not None:
        spec['default'] = default
    return {'parameter': spec}


def parse_block(model_cls, spec, where: str):
    """
    Return the ``model_cls`` (a pydantic model) of a run-file block ``spec``, or one error line.

    Every error of the model — not a mapping, an unknown key, a key missing, a value of the wrong
    type, not finite or out of its bound, a rule of the model's validators — is one
    :class:`InvalidParameter` naming ``where`` or ``where.key`` (e.g. ``inverter.deadtime``), the
    value as written and why, the lines the blocks gave before they were models. A validator
    states its rule by raising ``InvalidParameter(field, value, reason)`` (or a ValueError, which
    names the field it validates). A model instance is returned as it is.
    """
    if isinstance(spec, model_cls):
        return spec
    try:
        return model_cls.model_validate(dict(spec) if isinstance(spec, Mapping) else spec)
    except ValidationError as exc:
        raise block_error(model_cls, spec, where, exc.errors()) from None


def literal_choices(annotation):
    """Return the names a field's type allows (a ``Literal``, or an optional one), or None."""
    if get_origin(annotation) is Literal:
        return get_args(annotation)
    inner = [a for a in get_args(annotation) if get_origin(a) is Literal]
    return get_args(inner[0]) if len(inner) == 1 else None


def choice_error(value, choices):
    """
    Return why ``value`` is not one of ``choices`` (the names, or a ``Literal`` type), or None.

    The one text a choice's refusal gives: a run file's, a model field's (:func:`block_error`),
    a node parameter's (im_common.node_params).
    """
    names = literal_choices(choices)
    names = tuple(choices) if names is None else names     # a tuple, a dict's keys, ...
    if value in names:
        return None
    return f"must be one of {', '.join(map(str, names))}"


def check_choice(name: str, value, choices) -> None:
    """Refuse ``value`` unless it is one of ``choices``: one :class:`InvalidParameter` line."""
    why = choice_error(value, choices)
    if why is not None:
        raise InvalidParameter(name, value, why)


def block_error(model_cls, spec, where: str, errors) -> InvalidParameter:
    """
    Return the one :class:`InvalidParameter` of a block's pydantic ``errors``.

    The first of: not a mapping; an unknown key (in the order written); a bad value (in the order
    written); a missing key (in the model's order); a rule across fields. An empty ``where``
    names the key alone (a configuration that is no run-file block: ``strategy``, not
    ``.strategy``); a value not written (a default the model chose) is the one it refused.
    """
    keys = list(model_cls.model_fields)
    written = list(spec) if isinstance(spec, Mapping) else []

    def rank(err):
        loc, kind = err['loc'], err['type']
        if not loc:
            return (4 if kind == 'value_error' else 0, 0)
        key = loc[0]
        at = written.index(key) if key in written else len(written)
        if kind in ('extra_forbidden', 'invalid_key'):
            return (1, at)
        if kind == 'missing':
            return (3, keys.index(key) if key in keys else 0)
        return (2, at)

    err = min(errors, key=rank)
    loc, kind, ctx = err['loc'], err['type'], err.get('ctx') or {}
    key = loc[0] if loc else None
    name = where if key is None else _dotted(where, key)
    if key is None:
        value = spec
    elif isinstance(spec, Mapping) and key in spec:
        value = spec[key]
    else:
        value = err.get('input') if kind != 'missing' else None
    if kind == 'value_error' and isinstance(ctx.get('error'), InvalidParameter):
        rule = ctx['error']
        return InvalidParameter(_dotted(where, rule.name) if rule.name else where, rule.value,
                                rule.reason)
    if kind == 'value_error':
        return InvalidParameter(name, value, str(ctx.get('error', err['msg'])))
    if key is None:
        return InvalidParameter(where, spec, 'must be a mapping of ' + ', '.join(keys))
    if kind in ('extra_forbidden', 'invalid_key'):
        return InvalidParameter(name, value, f"unknown key (known: {', '.join(keys)})")
    if kind == 'missing':
        return InvalidParameter(name, None, 'is missing')
    if kind in _BOUNDS or kind in _TYPES:
        return InvalidParameter(name, value, value_reason(err))
    if kind == 'literal_error' and key in model_cls.model_fields:
        try:
            check_choice(name, value, literal_choices(model_cls.model_fields[key].annotation))
        except InvalidParameter as exc:
            return exc
    return InvalidParameter(name, value, err['msg'])


def value_reason(err) -> str:
    """
    Say why a value was refused, from one pydantic error: the one text of a bound or a type.

    ``must be >= 0``, ``must be a real number``, ``must be finite``; pydantic's own message for
    any other kind (:func:`block_error` names the key around it).
    """
    kind, ctx = err['type'], err.get('ctx') or {}
    if kind in _BOUNDS:
        bound, sign = _BOUNDS[kind]
        return f'must be {sign} {ctx[bound]:g}'
    if kind == 'float_type' and isinstance(err.get('input'), int) \
            and not isinstance(err.get('input'), bool):
        return 'must be finite'         # an int beyond a float's range
    if kind in _TYPES:
        return _TYPES[kind]
    return err['msg'][:1].lower() + err['msg'][1:]


def _dotted(where: str, key) -> str:
    """Return ``where.key``, or ``key`` alone when ``where`` is empty."""
    return f'{where}.{key}' if where else str(key)
