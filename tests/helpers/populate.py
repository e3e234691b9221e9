"""Fill any rosidl-generated message with deterministic non-default values.

Used by the round-trip tests so that every field of every abp_msgs type is
exercised on the wire, including nested messages, arrays and sequences.
"""

import importlib
import math

from rosidl_parser.definition import (
    AbstractNestedType,
    AbstractString,
    AbstractWString,
    Array,
    BasicType,
    BoundedSequence,
    NamespacedType,
)

_INTEGER_LIMITS = {
    'int8': 127, 'uint8': 255, 'int16': 32767, 'uint16': 65535, 'int32': 2**31 - 1,
    'uint32': 2**32 - 1, 'int64': 2**63 - 1, 'uint64': 2**64 - 1, 'char': 255, 'octet': 255,
}


def _message_class(namespaced_type):
    module = importlib.import_module('.'.join(namespaced_type.namespaces))
    return getattr(module, namespaced_type.name)


def _value(slot_type, seed):
    if isinstance(slot_type, BasicType):
        name = slot_type.typename
        if name == 'boolean':
            return seed % 2 == 1
        if name in ('float', 'double'):
            return float(seed) + 0.25 if name == 'float' else math.pi * seed
        if name == 'octet':
            return bytes([seed % 256])
        return (seed * 7919) % (_INTEGER_LIMITS[name] + 1)
    if isinstance(slot_type, (AbstractString, AbstractWString)):
        return f'value-{seed}'
    if isinstance(slot_type, NamespacedType):
        return populate(_message_class(slot_type)(), seed)
    raise TypeError(f'unsupported slot type {slot_type!r}')


def populate(msg, seed=1):
    """Set every field of `msg` to a value derived from `seed`; returns `msg`."""
    for index, (name, slot_type) in enumerate(zip(msg.__slots__, msg.SLOT_TYPES)):
        field_seed = seed * 31 + index + 1
        if isinstance(slot_type, AbstractNestedType):
            if isinstance(slot_type, Array):
                length = slot_type.size
            elif isinstance(slot_type, BoundedSequence):
                length = min(2, slot_type.maximum_size)
            else:
                length = 2
            values = [_value(slot_type.value_type, field_seed + k) for k in range(length)]
            setattr(msg, name.lstrip('_'), values)
        else:
            setattr(msg, name.lstrip('_'), _value(slot_type, field_seed))
    return msg
