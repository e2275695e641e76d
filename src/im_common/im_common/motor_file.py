"""
The motor file's typed model, generated from the motor's one home (:mod:`im_common.params`).

A motor file is a ROS 2 parameters file for every node (``/**: {ros__parameters: {...}}``) whose
mapping holds :class:`~im_common.params.MotorParams`' fields — their ranges
(:data:`~im_common.params.MOTOR_RANGES`), descriptions (:data:`~im_common.params.MOTOR_DOC`),
which are required (:data:`~im_common.params.REQUIRED_MOTOR_FIELDS`) — and the real plant's
blocks (:data:`~im_common.params.MOTOR_BLOCK_MODELS`). The models here are built from those, so
nothing is declared twice: :data:`MotorFields` (a motor, as a motor file or a run file's inline
``motor:`` gives it), :data:`MotorEstimates` (a run file's ``estimates:``, any fields over the
motor's) and :data:`MotorFile` (the file's layout). Their JSON Schema is
``share/im_common/schema/motor.schema.json`` (:mod:`im_bringup.schemas`, docs/running.md).

The schema cannot tell ``2`` from ``2.0`` (JSON has one number type): :func:`~im_common.params.
motor_from_dict` still refuses an integer where a real number is expected, as a ROS parameter is
typed, and says to write ``2.0``.
"""
from __future__ import annotations

from typing import Optional

from pydantic import create_model, Field

from .params import (MOTOR_BLOCK_MODELS, MOTOR_DOC, MOTOR_RANGES, MotorParams,
                     REQUIRED_MOTOR_FIELDS, THESIS_MOTOR)
from .validation import BLOCK_CONFIG

#: the motor file's top-level layout: every node's parameters
EVERY_NODE = '/**'


def _field(name: str, required: bool):
    lo, hi = MOTOR_RANGES[name]
    kind = int if name == 'pole_pairs' else float
    doc = MOTOR_DOC.get(name, 'pole pairs v')
    if required and name in REQUIRED_MOTOR_FIELDS:
        return kind, Field(ge=lo, le=hi, description=doc)
    default = getattr(THESIS_MOTOR, name) if required else None
    return (kind if required else Optional[kind]), Field(default, ge=lo, le=hi, description=doc)


def _motor_model(name: str, required: bool, doc: str):
    fields = {f: _field(f, required) for f in MotorParams.__dataclass_fields__}
    for block, model in MOTOR_BLOCK_MODELS.items():
        fields[block] = (Optional[model], Field(None, description=f"the real plant's {block} "
                                                'block (docs/plant.md; used when a run asks)'))
    return create_model(name, __config__=BLOCK_CONFIG, __doc__=doc,
                        **fields)


#: a motor: the required fields, the others at the thesis motor's values, its blocks
MotorFields = _motor_model('MotorFields', True, 'The fields of a motor (SI; docs/motors.md).')
#: a run file's ``estimates:``: any fields, over the plant motor's
MotorEstimates = _motor_model('MotorEstimates', False,
                              "The drive's model of the motor: these fields over the motor's.")
_Parameters = create_model('MotorParameters', __config__=BLOCK_CONFIG,
                           ros__parameters=(MotorFields, Field(description='the motor')))
#: the motor file: ``/**: {ros__parameters: {<the motor's fields>}}``
MotorFile = create_model('MotorFile', __config__=dict(BLOCK_CONFIG, title='IM drive motor file'),
                         every_node=(_Parameters, Field(alias=EVERY_NODE,
                                                        description="every node's parameters")))
