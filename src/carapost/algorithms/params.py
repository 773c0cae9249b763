"""Declaring algorithm parameters once: field metadata, one validator, mapping helpers.

Each algorithm parameter object (``BlobParameters``, ``TrackingParameters``...) is a
frozen dataclass whose fields are declared with :func:`param`. The field carries its
range and, when it is a property of the Properties pane, its section, displayed label
(the reference guide's name), unit and help text. From that one declaration:

- :func:`validate`, called from the dataclass's ``__post_init__``, checks every field
  and names the parameter by its label in the error;
- the properties registry (:mod:`carapost.model.properties`) builds the algorithm
  sections of the Properties pane from :func:`property_fields`;
- :func:`from_mapping` and :func:`to_mapping` convert between a parameter object and
  property values keyed by property key (for example the project's properties).

Fields declared with :func:`param` but without a ``section`` are internal tunables:
checked like the others, but not shown in the Properties pane. Fields declared as plain
dataclass fields are not checked at all.

Examples
--------
>>> from dataclasses import dataclass
>>> @dataclass(frozen=True)
... class SmoothingParameters:
...     window: int = param(5, label="Smoothing Window", section="Smoothing", unit="frames",
...                         min=1, max=99, help="Frames averaged around each frame.")
...     strength: float = param(0.5, min=0.0, max=1.0)
...     verbose: bool = False
...     def __post_init__(self) -> None:
...         validate(self)
>>> SmoothingParameters(window=0)
Traceback (most recent call last):
...
ValueError: Smoothing Window (SmoothingParameters.window) must be between 1 and 99 (got 0)
>>> SmoothingParameters(strength=2)
Traceback (most recent call last):
...
ValueError: SmoothingParameters.strength must be between 0 and 1 (got 2)
>>> [f.name for f, info in property_fields(SmoothingParameters)]
['window']
>>> from_mapping(SmoothingParameters, {"window": 9, "other": 1}, verbose=True)
SmoothingParameters(window=9, strength=0.5, verbose=True)
>>> to_mapping(SmoothingParameters())
{'window': 5}
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

__all__ = [
    "BLOB",
    "INITIALIZE_3D",
    "INITIALIZE_FROM_ROM",
    "TARGET_TRACKER",
    "TRACKING",
    "TRIANGULATION",
    "Allowed",
    "ParamInfo",
    "check_number",
    "check_value",
    "format_value",
    "from_mapping",
    "param",
    "param_info",
    "property_fields",
    "range_text",
    "shown",
    "to_mapping",
    "validate",
]

# Properties pane sections that algorithm parameter objects fill (display names).
BLOB = "Blob Parameters"
INITIALIZE_3D = "Initialize 3D Parameters"
INITIALIZE_FROM_ROM = "Initialize From ROM Parameters"
TRACKING = "Tracking Parameters"
TRIANGULATION = "Triangulation Parameters"
TARGET_TRACKER = "Target Tracker"

#: Key of :class:`ParamInfo` in ``dataclasses.Field.metadata``.
_META = "carapost.param"


@dataclass(frozen=True)
class ParamInfo:
    """What :func:`param` records about one field.

    Attributes
    ----------
    label : str or None
        Name shown to the user (the reference guide's name); None for a tunable.
    section : str or None
        Properties pane section; None for an internal tunable (not a property).
    key : str or None
        Property key when it differs from the field name.
    unit : str
        Unit shown beside the value (``"px"``, ``"mm"``, ``"0-1"``...).
    minimum, maximum : float or None
        Bounds of a number (of each element of a tuple); None for no bound.
    min_exclusive, max_exclusive : bool
        The bound itself is not allowed.
    choices : tuple of str or None
        Allowed values of a text field.
    help : str
        One-line description for tooltips and docs/properties.md.
    """

    label: str | None = None
    section: str | None = None
    key: str | None = None
    unit: str = ""
    minimum: float | None = None
    maximum: float | None = None
    min_exclusive: bool = False
    max_exclusive: bool = False
    choices: tuple[str, ...] | None = None
    help: str = ""

    @property
    def is_property(self) -> bool:
        """Whether the field is shown in the Properties pane."""
        return self.section is not None

    def range_text(self) -> str:
        """Allowed values in words (see :func:`range_text`)."""
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        return range_text(self.minimum, self.maximum, self.min_exclusive, self.max_exclusive)


def param(
    default: Any,
    *,
    label: str | None = None,
    section: str | None = None,
    key: str | None = None,
    unit: str = "",
    min: float | None = None,
    max: float | None = None,
    min_exclusive: bool = False,
    max_exclusive: bool = False,
    choices: tuple[str, ...] | None = None,
    help: str = "",
) -> Any:
    """A dataclass field with its range and, for a property, its label and section.

    Parameters
    ----------
    default : bool, int, float, str or tuple of float
        Default value (its type is the field's type: write ``4.0`` for a float).
    label : str, optional
        Displayed name (the reference guide's name); required with ``section``.
    section : str, optional
        Properties pane section; without it the field is an internal tunable.
    key : str, optional
        Property key, when it differs from the field name.
    unit : str
        Unit shown beside the value.
    min, max : float, optional
        Bounds (inclusive unless ``min_exclusive`` / ``max_exclusive``).
    min_exclusive, max_exclusive : bool
        Exclude the bound itself (``min=0, min_exclusive=True``: positive).
    choices : tuple of str, optional
        Allowed values of a text field.
    help : str
        One-line description (shown as the tooltip).

    Returns
    -------
    dataclasses.Field
        To be assigned to the class attribute.

    Raises
    ------
    TypeError
        If ``section`` is given without ``label`` or the default is mutable.
    """
    if section is not None and not label:
        raise TypeError("a property field needs a label")
    if isinstance(default, list | dict | set):
        raise TypeError("param defaults must be immutable (use a tuple)")
    info = ParamInfo(label, section, key, unit, min, max, min_exclusive, max_exclusive,
                     choices, help)
    return dataclasses.field(default=default, metadata={_META: info})


def param_info(field: dataclasses.Field) -> ParamInfo | None:
    """The :class:`ParamInfo` of a field, or None for a plain field."""
    return field.metadata.get(_META)


def _key(field: dataclasses.Field) -> str:
    info = param_info(field)
    return info.key if info is not None and info.key else field.name


def property_fields(cls: type) -> list[tuple[dataclasses.Field, ParamInfo]]:
    """The fields of a parameter class that are properties, in declaration order.

    Parameters
    ----------
    cls : dataclass type

    Returns
    -------
    list of (dataclasses.Field, ParamInfo)
    """
    out = []
    for f in dataclasses.fields(cls):
        info = param_info(f)
        if info is not None and info.is_property:
            out.append((f, info))
    return out


class _Lookup(Protocol):
    def __contains__(self, key: object) -> bool: ...
    def __getitem__(self, key: str) -> Any: ...


def from_mapping(cls: type, mapping: _Lookup, **overrides: Any) -> Any:
    """Build a parameter object from property values keyed by property key.

    This is the one way to turn the project's properties into algorithm parameters.

    Parameters
    ----------
    cls : dataclass type
        The parameter class, e.g. ``BlobParameters``.
    mapping : mapping of str to Any
        Values by key: a :class:`~carapost.model.properties.Properties`, one of its
        sections, or a plain dict. Keys the class does not have are ignored; fields
        missing from it keep their defaults. Internal tunables are read by field name.
    **overrides
        Field values (by field name) that take precedence over ``mapping``.

    Returns
    -------
    instance of ``cls``

    Raises
    ------
    ValueError
        If a value is refused by the class's validation.
    TypeError
        If an override names no field.
    """
    kw = {}
    for f in dataclasses.fields(cls):
        k = _key(f)
        if k in mapping:
            kw[f.name] = mapping[k]
    kw.update(overrides)
    return cls(**kw)


def to_mapping(obj: Any) -> dict[str, Any]:
    """Property key -> value of the property fields of a parameter object.

    The inverse of :func:`from_mapping` for properties: ``props.update(to_mapping(p))``
    stores ``p`` in the project's properties (internal tunables are not included).
    """
    return {_key(f): getattr(obj, f.name) for f, _ in property_fields(type(obj))}


# ---- checking values --------------------------------------------------------------------
def format_value(value: Any) -> str:
    """A value as shown in messages and docs (``0.4``, ``50``, ``True``, ``active``)."""
    if isinstance(value, bool | np.bool_):
        return str(bool(value))
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        return f"{float(value):g}"
    return str(value)


def shown(value: Any) -> str:
    """A refused value as quoted in messages: numbers plainly (``1.5``, not
    ``np.float64(1.5)``), anything else by ``repr``."""
    if isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_):
        return format_value(value)
    return repr(value)


def range_text(
    minimum: float | None,
    maximum: float | None,
    min_exclusive: bool = False,
    max_exclusive: bool = False,
) -> str:
    """Bounds in words, e.g. ``"between 0 and 1"``; empty when there is none.

    Examples
    --------
    >>> range_text(0, 1)
    'between 0 and 1'
    >>> range_text(0, 1000, min_exclusive=True)
    'greater than 0 and at most 1000'
    >>> range_text(1, None)
    'at least 1'
    """
    low = high = ""
    if minimum is not None:
        low = f"{'greater than' if min_exclusive else 'at least'} {format_value(minimum)}"
    if maximum is not None:
        high = f"{'less than' if max_exclusive else 'at most'} {format_value(maximum)}"
    if low and high:
        if not (min_exclusive or max_exclusive):
            return f"between {format_value(minimum)} and {format_value(maximum)}"
        return f"{low} and {high}"
    return low or high


def check_number(
    value: Any,
    label: str,
    *,
    integer: bool = False,
    minimum: float | None = None,
    maximum: float | None = None,
    min_exclusive: bool = False,
    max_exclusive: bool = False,
) -> int | float:
    """Check that ``value`` is a finite number within bounds and return it coerced.

    Integers are accepted for floats, integral floats for integers and numpy scalars
    for both; booleans are refused.

    Parameters
    ----------
    value : Any
    label : str
        Name of the parameter in the message.
    integer : bool
        A whole number is required (returned as ``int``; otherwise ``float``).
    minimum, maximum, min_exclusive, max_exclusive
        Bounds, as in :func:`range_text`.

    Returns
    -------
    int or float

    Raises
    ------
    ValueError
        ``"<label> must be <what is allowed> (got <value>)"``.
    """
    allowed = range_text(minimum, maximum, min_exclusive, max_exclusive)

    def refuse(expected: str) -> ValueError:
        return ValueError(f"{label} must be {expected.rstrip()} (got {shown(value)})")

    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
        raise refuse(f"a number {allowed}")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        raise refuse(f"a finite number {allowed}")
    if integer:
        if number != int(number):
            raise refuse(f"a whole number {allowed}")
        coerced: int | float = int(number)
    else:
        coerced = number
    if minimum is not None and (coerced <= minimum if min_exclusive else coerced < minimum):
        raise refuse(allowed)
    if maximum is not None and (coerced >= maximum if max_exclusive else coerced > maximum):
        raise refuse(allowed)
    return coerced


class Allowed(Protocol):
    """What :func:`check_value` reads of a declaration: a :class:`ParamInfo`, or a
    :class:`carapost.model.properties.PropertySpec`."""

    @property
    def minimum(self) -> float | None: ...
    @property
    def maximum(self) -> float | None: ...
    @property
    def min_exclusive(self) -> bool: ...
    @property
    def max_exclusive(self) -> bool: ...
    @property
    def choices(self) -> tuple[str, ...] | None: ...
    def range_text(self) -> str: ...


def check_value(value: Any, info: Allowed, kind: type, label: str) -> Any:
    """Check one value of a field of type ``kind`` against ``info``; return it coerced.

    Raises
    ------
    ValueError
        Naming ``label`` and what is allowed.
    """
    if kind is bool:
        if isinstance(value, bool | np.bool_):
            return bool(value)
        raise ValueError(f"{label} must be True or False (got {shown(value)})")
    if kind is int or kind is float:
        return check_number(value, label, integer=kind is int, minimum=info.minimum,
                            maximum=info.maximum, min_exclusive=info.min_exclusive,
                            max_exclusive=info.max_exclusive)
    if kind is tuple:
        if not isinstance(value, tuple | list):
            raise ValueError(f"{label} must be a tuple of numbers (got {shown(value)})")
        return tuple(check_number(v, f"{label}[{i}]", minimum=info.minimum,
                                  maximum=info.maximum, min_exclusive=info.min_exclusive,
                                  max_exclusive=info.max_exclusive)
                     for i, v in enumerate(value))
    if info.choices is not None:
        if isinstance(value, str):
            for choice in info.choices:
                if value.strip().lower() == choice.lower():
                    return choice
        raise ValueError(f"{label} must be {info.range_text()} (got {shown(value)})")
    if isinstance(value, str):
        return value
    raise ValueError(f"{label} must be text (got {shown(value)})")


def _declared(obj: Any) -> Iterator[tuple[dataclasses.Field, ParamInfo]]:
    for f in dataclasses.fields(obj):
        info = param_info(f)
        if info is not None:
            yield f, info


def validate(obj: Any) -> None:
    """Check every :func:`param` field of a parameter object (call in ``__post_init__``).

    The values are checked, not converted: the object keeps what it was given.

    Raises
    ------
    ValueError
        For the first field refused, named ``"<label> (<Class>.<field>)"`` (or
        ``"<Class>.<field>"`` for a tunable) with the allowed range, e.g.
        ``"Black Threshold (BlobParameters.black_threshold) must be between 0 and 1
        (got 1.5)"``.
    """
    cls = type(obj).__name__
    for f, info in _declared(obj):
        name = f"{cls}.{f.name}"
        label = f"{info.label} ({name})" if info.label else name
        check_value(getattr(obj, f.name), info, type(f.default), label)
