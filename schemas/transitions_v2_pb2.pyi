from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class TransitionBatch(_message.Message):
    __slots__ = ("schema_version", "first_index", "count", "motor_dim", "sensor_shape", "m_t", "m_t1", "s_t", "s_t1", "privileged", "episodes")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    FIRST_INDEX_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    MOTOR_DIM_FIELD_NUMBER: _ClassVar[int]
    SENSOR_SHAPE_FIELD_NUMBER: _ClassVar[int]
    M_T_FIELD_NUMBER: _ClassVar[int]
    M_T1_FIELD_NUMBER: _ClassVar[int]
    S_T_FIELD_NUMBER: _ClassVar[int]
    S_T1_FIELD_NUMBER: _ClassVar[int]
    PRIVILEGED_FIELD_NUMBER: _ClassVar[int]
    EPISODES_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    first_index: int
    count: int
    motor_dim: int
    sensor_shape: _containers.RepeatedScalarFieldContainer[int]
    m_t: _containers.RepeatedScalarFieldContainer[float]
    m_t1: _containers.RepeatedScalarFieldContainer[float]
    s_t: SensorColumn
    s_t1: SensorColumn
    privileged: Privileged
    episodes: Episodes
    def __init__(self, schema_version: _Optional[int] = ..., first_index: _Optional[int] = ..., count: _Optional[int] = ..., motor_dim: _Optional[int] = ..., sensor_shape: _Optional[_Iterable[int]] = ..., m_t: _Optional[_Iterable[float]] = ..., m_t1: _Optional[_Iterable[float]] = ..., s_t: _Optional[_Union[SensorColumn, _Mapping]] = ..., s_t1: _Optional[_Union[SensorColumn, _Mapping]] = ..., privileged: _Optional[_Union[Privileged, _Mapping]] = ..., episodes: _Optional[_Union[Episodes, _Mapping]] = ...) -> None: ...

class Episodes(_message.Message):
    __slots__ = ("episode", "step")
    EPISODE_FIELD_NUMBER: _ClassVar[int]
    STEP_FIELD_NUMBER: _ClassVar[int]
    episode: _containers.RepeatedScalarFieldContainer[int]
    step: _containers.RepeatedScalarFieldContainer[int]
    def __init__(self, episode: _Optional[_Iterable[int]] = ..., step: _Optional[_Iterable[int]] = ...) -> None: ...

class SensorColumn(_message.Message):
    __slots__ = ("float32", "uint8")
    FLOAT32_FIELD_NUMBER: _ClassVar[int]
    UINT8_FIELD_NUMBER: _ClassVar[int]
    float32: FloatValues
    uint8: bytes
    def __init__(self, float32: _Optional[_Union[FloatValues, _Mapping]] = ..., uint8: _Optional[bytes] = ...) -> None: ...

class FloatValues(_message.Message):
    __slots__ = ("values",)
    VALUES_FIELD_NUMBER: _ClassVar[int]
    values: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, values: _Optional[_Iterable[float]] = ...) -> None: ...

class Privileged(_message.Message):
    __slots__ = ("p_t", "p_t1", "shift_t", "shift_t1")
    P_T_FIELD_NUMBER: _ClassVar[int]
    P_T1_FIELD_NUMBER: _ClassVar[int]
    SHIFT_T_FIELD_NUMBER: _ClassVar[int]
    SHIFT_T1_FIELD_NUMBER: _ClassVar[int]
    p_t: _containers.RepeatedScalarFieldContainer[float]
    p_t1: _containers.RepeatedScalarFieldContainer[float]
    shift_t: _containers.RepeatedScalarFieldContainer[float]
    shift_t1: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, p_t: _Optional[_Iterable[float]] = ..., p_t1: _Optional[_Iterable[float]] = ..., shift_t: _Optional[_Iterable[float]] = ..., shift_t1: _Optional[_Iterable[float]] = ...) -> None: ...

class RegularSampling(_message.Message):
    __slots__ = ("schema_version", "count", "motor_dim", "m", "p")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    MOTOR_DIM_FIELD_NUMBER: _ClassVar[int]
    M_FIELD_NUMBER: _ClassVar[int]
    P_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    count: int
    motor_dim: int
    m: _containers.RepeatedScalarFieldContainer[float]
    p: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, schema_version: _Optional[int] = ..., count: _Optional[int] = ..., motor_dim: _Optional[int] = ..., m: _Optional[_Iterable[float]] = ..., p: _Optional[_Iterable[float]] = ...) -> None: ...
