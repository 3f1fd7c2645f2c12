"""The parameter schema (:mod:`planar_vo.core.config`) declared on an rclpy node.

Each parameter is first declared with dynamic typing and no range, so that only the schema
judges the start-up value (and an integer for a float is accepted: ``-p camera_height:=1``);
then the value is made a float if it should be, and the typed, ranged descriptor that
``ros2 param describe`` shows is set. Public rclpy API only.
"""

from __future__ import annotations

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from planar_vo.core import config
from planar_vo.ros.errors import StartupError

__all__ = ['StartupError', 'declare_schema', 'SCHEMA_BY_NAME']

SCHEMA_BY_NAME = {p.name: p for p in config.SCHEMA}


def declare_schema(node: Node) -> config.Params:
    """Declare every schema parameter on ``node``; their checked values.

    Also registers the callbacks that accept integers for floats and refuse out-of-range
    values at run time with the schema's reason. Raises StartupError for a bad start-up
    value (command line or params file).
    """
    rejected = []

    def validate(params: list[Parameter]) -> SetParametersResult:
        for prm in params:
            spec = SCHEMA_BY_NAME.get(prm.name)
            if spec is None:
                continue
            try:
                spec.check(prm.value)
            except config.ConfigError as err:
                rejected.append(str(err))
                return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    node.add_pre_set_parameters_callback(_ints_to_floats)
    node.add_on_set_parameters_callback(validate)
    for spec in config.SCHEMA:
        try:
            value = node.declare_parameter(spec.name, spec.default,
                                           _descriptor(spec, loose=True)).value
        except (InvalidParameterValueException, InvalidParameterTypeException) as err:
            raise StartupError(f'invalid parameter: {rejected[-1] if rejected else err}') \
                from None
        if isinstance(spec.default, float) and not isinstance(value, float):
            node.set_parameters([Parameter(spec.name, value=float(value))])
        if not spec.read_only:  # rclpy keeps read-only descriptors as declared
            node.set_descriptor(spec.name, _descriptor(spec))
    return config.Params(**{s.name: s.check(node.get_parameter(s.name).value)
                            for s in config.SCHEMA})


def _ints_to_floats(params: list[Parameter]) -> list[Parameter]:
    out = []
    for prm in params:
        spec = SCHEMA_BY_NAME.get(prm.name)
        if (spec is not None and isinstance(spec.default, float)
                and prm.type_ == Parameter.Type.INTEGER):
            prm = Parameter(prm.name, value=float(prm.value))
        out.append(prm)
    return out


def _descriptor(spec: config.Param, *, loose: bool = False) -> ParameterDescriptor:
    """The parameter's descriptor; ``loose``: any type and no range (declaration only)."""
    desc = ParameterDescriptor(description=spec.description, read_only=spec.read_only,
                               dynamic_typing=loose)
    if not loose:
        desc.type = Parameter.Type.from_parameter_value(spec.default).value
    if isinstance(spec.default, float) and not loose:
        desc.floating_point_range = [FloatingPointRange(
            from_value=float(spec.low), to_value=float(spec.high), step=0.0)]
    elif isinstance(spec.default, int) and not isinstance(spec.default, bool) and not loose:
        desc.integer_range = [IntegerRange(
            from_value=int(spec.low), to_value=int(spec.high), step=1)]
    elif spec.choices:
        desc.additional_constraints = 'one of: ' + ', '.join(spec.choices)
    return desc
