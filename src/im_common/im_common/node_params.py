"""
Parameters several nodes declare the same way: the motor, the period, the run length.

Also a run-file block's parameters, generated from its pydantic model (:func:`declare_block`,
:func:`block_parameters`: the plant's ``inverter.*`` and ``sensors.*``, the motor's
``saturation.*`` and ``thermal.*``, the drive's ``saturation_model.*``, the variation's
``variation.<parameter>.*``), and a node's configuration model's (:func:`declare_model`,
:func:`model_arguments`: the controller's).
"""
from __future__ import annotations

from typing import Mapping, Optional

from .compensation import compensation_from_parameters, DEFAULT_CURRENT_BAND
from .delay import CommandDelay, MAX_DELAY
from .params import (ELECTRICAL_NAMES, MOTOR_BLOCK_MODELS, MOTOR_DOC, MOTOR_RANGES, MotorParams,
                     parameter_error, ParameterVariation, THESIS_MOTOR, VariationBlock,
                     warn_motor_defaults)
from .saturation import saturated_model, SaturationBlock
from .validation import choice_error, InvalidParameter, literal_choices, parse_block


def declare_motor(node, base: MotorParams = THESIS_MOTOR, what: str = 'motor',
                  blocks: Optional[dict] = None, warn_defaults: bool = False) -> MotorParams:
    """
    Declare the motor parameters on ``node`` (defaults: the thesis motor) and validate them.

    A motor file (``--params-file motor.yaml`` with ``/**:``) sets them on every node at once.

    ``blocks``, when given, receives the motor file's ``saturation`` and ``thermal`` blocks (the
    real plant's, docs/plant.md): their models (:data:`im_common.params.MOTOR_BLOCK_MODELS`) from
    the parameters ``saturation.*``, ``thermal.*`` (:func:`declare_block`; a motor file's nested
    mapping ``saturation: {law: power, beta: 1.4, S: 7.0}`` gives them, and turns the block on),
    None when absent; every node declares them, since a motor file reaches every node.

    ``warn_defaults``: when a motor was given (its electrical fields), warn once, one line each,
    of the fields it lacks and the defaults they take (:func:`im_common.params.motor_defaults`).

    Raises :class:`im_common.params.InvalidParameter` naming the parameter (e.g. σ ≤ 0 names L_sr).
    """
    values = {}
    for name, doc in MOTOR_DOC.items():
        values[name] = node.param(name, float(getattr(base, name)), f'{what}: {doc}',
                                  *MOTOR_RANGES[name])
    values['pole_pairs'] = node.param('pole_pairs', int(base.pole_pairs),
                                      f'{what}: pole pairs v', *MOTOR_RANGES['pole_pairs'])
    given = getattr(node, '_parameter_overrides', {})
    for name, model in MOTOR_BLOCK_MODELS.items():     # a motor file's real-plant blocks
        if name in given:       # the text a motor file once held: it would act on nothing now
            raise InvalidParameter(name, given[name].value, f'a block is a mapping now, '
                                   f'{name}: {{key: value, ...}} ({name}.* parameters; '
                                   'docs/plant.md)')
        block = declare_block(node, model, name, f"{what}: the real plant's {name} block, "
                              f'{name}.* (on when any is given: a motor file; docs/plant.md)',
                              on_when_given=True)
        if blocks is not None:
            blocks[name] = block
    motor = MotorParams(**values)
    given = set(getattr(node, '_parameter_overrides', {}))
    if warn_defaults and given.issuperset(ELECTRICAL_NAMES):
        warn_motor_defaults(f"node '{node.get_name()}' motor", given, motor,
                            log=node.get_logger().warning)
    return motor


def declare_compensation(node):
    """
    Declare the inverter-error compensation: ``comp_v_dead``, ``comp_r_on``, ``comp_current_band``.

    The controller, observer and adapter declare the same three (docs/compensation.md); returns
    the :class:`~im_common.compensation.InverterErrorModel`, or None when v_dead = r_on = 0.
    """
    doc = {'comp_v_dead': ('inverter error per phase: dead time t_d f_sw V_dc + device drop '
                           'v_on [V] (0 with comp_r_on 0: no compensation)', 0.0, 0.0, 1e4),
           'comp_r_on': ("inverter error per phase: the devices' on-state resistance [ohm]",
                         0.0, 0.0, 100.0),
           'comp_current_band': ('inverter error: the current over which its sign ramps from -1 '
                                 'to +1 is +-this [A]', DEFAULT_CURRENT_BAND, 0.0, 1e4)}
    values = {name: node.param(name, default, desc, lo, hi)
              for name, (desc, default, lo, hi) in doc.items()}
    return compensation_from_parameters(values)


def declare_saturation_model(node, params):
    """
    Declare ``saturation_model.*``: the drive's magnetizing curve (not enabled: the linear model).

    The observer and controller declare it (docs/plant.md §2, "The drive on the curve"): a
    saturation block's parameters (:class:`~im_common.saturation.SaturationBlock`,
    :func:`declare_block`). Returns the :class:`~im_common.saturation.SaturatedModel` of
    ``params`` on it, or None; a bad block is one error naming the parameter.
    """
    block = declare_block(node, SaturationBlock, 'saturation_model', "the drive's magnetizing "
                          'curve, saturation_model.*: the power law (beta, S) or a table '
                          '(false: the linear model; docs/plant.md section 2)')
    return saturated_model(block, params)


def declare_variation(node) -> Optional[VariationBlock]:
    """
    Declare ``variation.<name>.*`` of each electrical parameter: the plant's breakpoint variation.

    One block per parameter (:class:`~im_common.params.ParameterVariation`,
    :func:`declare_block`): ``variation.R_r.enabled``, ``.by``, ``.points``, ``.shape``,
    ``.sines``. Returns the :class:`~im_common.params.VariationBlock` of those enabled, or None.
    """
    parts = {name: declare_block(node, ParameterVariation, f'variation.{name}',
                                 f'variation schedule: {name} varies in time, '
                                 f'variation.{name}.* (docs/running.md)')
             for name in ELECTRICAL_NAMES}
    parts = {k: v for k, v in parts.items() if v is not None}
    return VariationBlock(**parts) if parts else None


def variation_parameters(block: VariationBlock) -> dict:
    """Return the node parameters of a variation (:func:`declare_variation`'s); no ROS import."""
    out = {}
    for name, part in block.parts().items():
        out.update(block_parameters(part, f'variation.{name}'))
    return out


def variation_from_parameters(values: Mapping) -> Optional[VariationBlock]:
    """Return the variation of a node's parameter ``values`` (:func:`declare_variation`'s)."""
    parts = {name: block_from_parameters(ParameterVariation, values, f'variation.{name}')
             for name in ELECTRICAL_NAMES}
    parts = {k: v for k, v in parts.items() if v is not None}
    return VariationBlock(**parts) if parts else None


#: the value of a block's parameter for a field that has no default (required): 'not given'.
#: ROS 2 has parameters without a value (statically typed, NOT_SET), but its parameter services
#: answer none of a get_parameters request naming one: ros2 param dump and the recorder would
#: get no parameter of the plant. 0 is no usable value of a positive field without a default, so
#: it stands for 'not given' (an optional field says its own in its metadata: the inverter's V_dc).
NOT_GIVEN = {float: 0.0, int: 0, str: ''}


def _parameter_spec(info):
    """
    Return a model field's node parameter: {'default'?, 'range', 'sentinels'}, {} or None.

    ``json_schema_extra={'parameter': ...}`` of the field (e.g.
    :class:`im_controller.control_law.ControllerConfig`'s); {} when the field says nothing (a
    block's fields: the parameter is the field); None when the field is no node parameter.
    """
    extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
    return extra.get('parameter', {})


def _shown(value) -> str:
    """Return a sentinel as a parameter description writes it (-1, 0, [0.0])."""
    return f'{value:g}' if isinstance(value, float) else repr(value)


def _block_fields(model_cls):
    """
    Yield each field of a model that is a node parameter: (field, default, choices, text, lo, hi).

    The default has the parameter's type (a float, an int, a string, a list of floats for a
    tuple); a field without one (required) gets :data:`NOT_GIVEN` of its type; a field whose
    metadata names the parameter's own default (a sentinel, :func:`_parameter_spec`) gets that.
    The text is the field's description, what each sentinel stands for and the field's bounds
    (gt/ge/lt/le); lo, hi the parameter's range (the metadata's; None: none).
    """
    signs = {'gt': '>', 'ge': '>=', 'lt': '<', 'le': '<='}
    for name, info in model_cls.model_fields.items():
        spec = _parameter_spec(info)
        if spec is None:
            continue
        kind = info.annotation
        choices = literal_choices(kind)
        required = info.is_required()
        default = NOT_GIVEN[kind] if required else spec.get('default', info.default)
        if isinstance(default, tuple):
            default = [float(x) for x in default]
        bounds = ', '.join(f'{signs[k]} {getattr(m, k):g}' for m in info.metadata for k in signs
                           if getattr(m, k, None) is not None)
        notes = '; '.join(f'{_shown(given)}: {meaning}'
                          for given, _, meaning in spec.get('sentinels', ()))
        text = info.description + (f' ({notes})' if notes else '') + (
            f"; {'otherwise ' if notes else ''}{bounds}" if bounds else '')
        if required:
            text += f'; required ({default!r}: not given)'
        lo, hi = spec.get('range', (None, None))
        yield name, default, choices, text, lo, hi


def declare_model(node, model_cls, live=()) -> dict:
    """
    Declare a node's parameters generated from its configuration model; return their values.

    One parameter per field of ``model_cls`` that is a node parameter (:func:`_block_fields`: the
    field's name, type, default or the sentinel its metadata gives, description, choices and the
    metadata's range), read-only unless named in ``live``. The values are the parameters', as
    declared: :func:`model_arguments` turns them into the model's.
    """
    return {name: node.param(name, default, text, lo, hi, read_only=name not in live,
                             choices=choices)
            for name, default, choices, text, lo, hi in _block_fields(model_cls)}


def model_arguments(model_cls, values: dict) -> dict:
    """
    Return the model's field values of node-parameter ``values`` (:func:`declare_model`'s).

    A sentinel (a field's metadata: -1, 0, [0.0]) is the value it stands for (None: the model's
    default, RATED, no limit, ...); a field whose sentinel is -1 refuses another negative value
    (:class:`~im_common.validation.InvalidParameter` naming it: it would never be read as the
    sentinel quietly). Names that are no field of the model pass as they are.
    """
    out = dict(values)
    for name, value in values.items():
        info = model_cls.model_fields.get(name)
        spec = _parameter_spec(info) if info is not None else None
        for given, stands_for, meaning in (spec or {}).get('sentinels', ()):
            if _is_sentinel(value, given):
                out[name] = stands_for
                break
            if given == -1.0 and _is_number(value) and value < 0:
                raise InvalidParameter(name, value, f'must be >= 0, or -1: {meaning}')
    return out


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_sentinel(value, given) -> bool:
    """Tell whether a parameter's value is the sentinel ``given`` (a number, or a list)."""
    if isinstance(given, list):
        return not isinstance(value, (str, bytes)) and hasattr(value, '__iter__') \
            and list(value) == given
    return _is_number(value) and value == given


def declare_block(node, model_cls, prefix: str, description: str, on_when_given: bool = False):
    """
    Declare a run-file block's parameters, generated from its pydantic model; return it or None.

    ``<prefix>.enabled`` (false, the default: no block, None) and one typed parameter per field of
    ``model_cls`` (:class:`im_common.inverter.Inverter`, :class:`im_plant.sensors.Sensors`),
    ``<prefix>.<field>``: the field's type (a tuple: an array), default, description (unit,
    meaning) and bounds. The values are read by :func:`block_from_parameters`. ``on_when_given``
    (a motor file's blocks, whose nested mapping gives the fields alone): ``<prefix>.enabled``
    defaults to true when any ``<prefix>.<field>`` is given.
    """
    fields = list(_block_fields(model_cls))
    given = getattr(node, '_parameter_overrides', {})
    implied = [f'{prefix}.{name}' for name, *_ in fields if f'{prefix}.{name}' in given] \
        if on_when_given and f'{prefix}.enabled' not in given else []
    values = {f'{prefix}.enabled': node.param(f'{prefix}.enabled', bool(implied), description)}
    for name, default, choices, text, _, _ in fields:
        values[f'{prefix}.{name}'] = node.param(f'{prefix}.{name}', default, f'{prefix}: {text}',
                                                choices=choices)
    try:
        return block_from_parameters(model_cls, values, prefix)
    except InvalidParameter as exc:     # one not given (missing): say what turned the block on
        trigger = (implied or [n for n in (f'{prefix}.enabled',) if n in given] or [None])[0]
        if trigger is None or exc.name in given:
            raise
        raise InvalidParameter(exc.name, exc.value, f'{exc.reason} ({trigger} is given, which '
                               f'turns the {prefix} block on)') from None


def block_from_parameters(model_cls, values: Mapping, prefix: str):
    """
    Return the block of node-parameter ``values`` (:func:`declare_block`'s), or None; no ROS.

    ``values``: {``<prefix>.enabled``: ..., ``<prefix>.<field>``: ...}, a name left out at its
    default. Enabled, the values are parsed into the model: an error is one line naming
    ``<prefix>.<field>`` (:func:`im_common.validation.parse_block`, the run file's lines), a
    required field left at :data:`NOT_GIVEN` is missing ('is missing'). A value equal to the
    parameter's default is the field's default (as if left out). Disabled, a field set to
    anything else is refused in one line: it would silently act on nothing.
    """
    spec = {}
    for name, default, _, _, _, _ in _block_fields(model_cls):
        value = values.get(f'{prefix}.{name}', default)
        if isinstance(default, list):
            value = list(value)                 # rclpy gives an array.array for a double array
        if value != default:
            spec[name] = value
    if not values.get(f'{prefix}.enabled', False):
        if spec:                # a setting given for a block that is off would act on nothing
            name = next(iter(spec))
            raise InvalidParameter(f'{prefix}.{name}', spec[name],
                                   f'set, but {prefix}.enabled is false (the block is off): '
                                   f'set {prefix}.enabled true, or leave {prefix}.{name} out')
        return None
    return parse_block(model_cls, spec, prefix)


def block_parameters(block, prefix: str) -> dict:
    """
    Return the node parameters of a block's model (:func:`declare_block`'s, flattened).

    ``{<prefix>.enabled: True, <prefix>.<field>: value, ...}``, every field (one left out, None
    or an empty tuple: the parameter's default, which stands for it); no ROS import.
    """
    out = {f'{prefix}.enabled': True}
    for name, default, _, _, _, _ in _block_fields(type(block)):
        value = getattr(block, name)
        if value is None or value == ():        # not given: the parameter's sentinel
            value = default
        out[f'{prefix}.{name}'] = [x if isinstance(x, str) else float(x) for x in value] \
            if isinstance(value, (tuple, list)) else value      # a tuple: an array
    return out


def declare_delay(node):
    """
    Declare ``delay`` and ``overlap`` (read-only); return the delay line and the command's lag.

    The plant's computational delay (the run file's ``inverter.delay``): the drive's parts that
    integrate the voltage the motor got (observer, adapter) hold the same line of commands.
    Overlapped (:func:`declare_overlap`), step k takes the command that acts over it, stamped
    t_k−d, straight from its step gate (the lag returned: d; else 0 and the node pushes the command
    of step k through the line itself).
    """
    d = node.param('delay', 0, 'computational delay [control periods] of the plant (the run '
                   "file's inverter.delay): the command of step k acts over step k + delay, and "
                   'this node integrates that voltage', 0, MAX_DELAY)
    return CommandDelay(d), (d if declare_overlap(node) else 0)


def declare_overlap(node) -> bool:
    """
    Declare ``overlap`` (read-only): a delayed step runs beside the command being computed.

    With a computational delay d >= 1 step k needs the command of step k − d only, so the plant
    integrates step k, and the observer and the adapter compute it, while the controller computes
    the command of step k (docs/architecture.md, "The delayed step overlapped"); the same numbers
    as the serial order. Without a delay it changes nothing.
    """
    return node.param('overlap', True, 'with a computational delay, compute step k from the '
                      'command of step k - delay as soon as it has come, beside the controller '
                      "computing step k's command (false: wait for the command of step k, the "
                      'serial order; the same numbers)')


def declare_run(node):
    """
    Declare T_s (read-only), duration and the timeouts.

    Returns (T_s, duration, input_timeout, startup_timeout).
    """
    T_s = node.param('T_s', 1e-4, 'control period T_s [s] (whole nanoseconds)', 1e-6, 0.1)
    duration = node.param('duration', 0.0,
                          'simulated run length [s]; the node stops cleanly after it (0: no end)',
                          0.0, 1e6)
    timeout = node.param('input_timeout', 5.0,
                         'wall-clock seconds to wait for an input of the current step before '
                         'reporting it and stopping', 0.01, 3600.0)
    startup = node.param('startup_timeout', 30.0,
                         'wall-clock seconds to wait for the first step (discovery)', 0.01, 3600.0)
    return T_s, duration, timeout, startup


class ConfigurationError(ValueError):
    """
    A node refuses its configuration (a parameter unknown, of the wrong type or out of range).

    The message is the one line every path prints (:func:`im_common.host.build_node`).
    """


def describe(description: str, lo=None, hi=None, read_only: bool = False, integer: bool = False,
             step=None):
    """Return the ``ParameterDescriptor`` of a parameter (its range, if ``lo`` and ``hi``)."""
    # heavy: rcl_interfaces (ROS messages), only in a node (run files load this module)
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
    d = ParameterDescriptor(description=description, read_only=read_only)
    if lo is not None and hi is not None:
        if integer:
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi),
                                            step=int(step or 1))]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi),
                                                         step=float(step or 0.0))]
    return d


def declare(node, name: str, default, description: str, lo=None, hi=None,
            read_only: bool = True, choices=None):
    """
    Declare a parameter of ``node`` with a descriptor and return its value (validated).

    A value given of the wrong type, out of range or not one of ``choices`` is refused with one
    :class:`ConfigurationError` line naming node and parameter (docs/architecture.md).
    """
    integer = isinstance(default, int) and not isinstance(default, bool)
    desc = describe(description + (f' (one of: {", ".join(choices)})' if choices else ''),
                    lo, hi, read_only=read_only, integer=integer)
    desc.dynamic_typing = not read_only     # a live value's type is checked by name (below)
    given = getattr(node, '_parameter_overrides', {}).get(name)
    bad = parameter_error(given.value, default, lo, hi) if given is not None else None
    value = given.value if bad else node.declare_parameter(name, default, desc).value
    if not bad and choices is not None:
        bad = choice_error(value, choices)
    if bad:
        raise ConfigurationError(f"invalid parameter '{name}' = {value!r} for node "
                                 f"'{node.get_name()}': {bad}")
    if not read_only:
        _live_checks(node)[name] = (default, lo, hi, choices)
    return value


def _live_checks(node) -> dict:
    """
    Return ``{name: (default, lo, hi, choices)}`` of the node's live parameters.

    The first call registers the node's first set-parameters callback: a value set while the node
    runs (``ros2 param set``) gets the start-up's type, range and choice rules, refused in one
    line naming the parameter. rclpy's own type check (before any callback) names none ("Wrong
    parameter type, expected 'Type.DOUBLE' got 'Type.STRING'"), so a live parameter is declared
    with dynamic typing and its type checked here.
    """
    checks = getattr(node, '_live_parameter_checks', None)
    if checks is None:
        checks = node._live_parameter_checks = {}
        node.add_on_set_parameters_callback(lambda params: live_refusal(node, params)
                                            or _accepted())
    return checks


def _accepted():
    from rcl_interfaces.msg import SetParametersResult  # heavy: ROS messages, as above
    return SetParametersResult(successful=True)


def live_refusal(node, parameters):
    """
    Return the refusal (a failed ``SetParametersResult``) of live values that break their rules.

    None when every value has its declared type, range and choices. rclpy calls the callback
    registered last first: a node's own set-parameters callback calls this before its checks.
    """
    from rcl_interfaces.msg import SetParametersResult  # heavy: ROS messages, as above
    checks = getattr(node, '_live_parameter_checks', {})
    for prm in parameters:
        if prm.name not in checks:
            continue
        default, lo, hi, choices = checks[prm.name]
        bad = parameter_error(prm.value, default, lo, hi)
        if not bad and choices is not None:
            bad = choice_error(prm.value, choices)
        if bad:
            return SetParametersResult(successful=False, reason='invalid parameter '
                                       f"'{prm.name}' = {prm.value!r}: {bad}")
    return None


def declare_lockstep(node) -> tuple:
    """Declare every lock-step node's own parameters: (rt_priority, graph_key_file, allowed)."""
    return (
        node.param('rt_priority', node.default_rt_priority,
                   'free_run, this node as its own process: SCHED_FIFO priority of its threads '
                   '(0: ordinary scheduling); needs root, CAP_SYS_NICE or an rtprio limit', 0, 99),
        node.param('graph_key_file', '',
                   "file holding the graph's key (empty: $IM_GRAPH_KEY_FILE, else "
                   '$ROS_HOME/im_drive/graph.key, created on first use); see docs/security.md'),
        node.param('allowed_publishers', '',
                   "publishers allowed on this node's inputs besides the topic table's: "
                   'space-separated topic=node items (e.g. /im/command/voltage=/ctl2)'))
