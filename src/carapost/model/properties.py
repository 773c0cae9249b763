"""The properties registry: every user-adjustable parameter with its default and range.

One typed table (:data:`SPECS`) describes each parameter of the Properties pane
(Selection, Blob Parameters, Initialize 3D Parameters, Initialize From ROM
Parameters, Tracking Parameters, Gap-Filling Parameters, Stabilization Parameters,
Export), the Target Tracker settings of the Tracker pane, and our own Triangulation
Parameters section. The property pane, the command line, the scripting API and the
project file all read this one table.

The algorithm sections are not written here: they are generated from the fields of the
algorithm parameter dataclasses (``BlobParameters``, ``Init3DParameters``,
``RomParameters``, ``TrackingParameters``, ``TriangulationParameters``,
``StabilizationParameters``, ``TargetTrackerParameters``), which declare label, unit,
range and help once with :func:`carapost.algorithms.params.param`. Selection,
Gap-Filling and Export have no parameter class yet and are declared below by hand.

Names, defaults and documented ranges follow the reference guide. Where the guide gives
no range (or no default), the value is our choice and the help text says so. The guide's
Shortcut section only lists keyboard shortcuts, so it holds no parameter. Purely GUI
preferences (the Display section's point label switches and font size, the Show Again
Flags, the Tracker pane's "Update ... Every Frame") are user settings
(:mod:`carapost.ui.settings`), not project properties.

Examples
--------
>>> props = Properties()
>>> props["black_threshold"]
0.4
>>> props.set("black_threshold", 1.5)
Traceback (most recent call last):
...
carapost.model.properties.PropertyError: Black Threshold must be between 0 and 1 (got 1.5)
>>> props.section("Blob Parameters")["find_black_blobs"]
True
"""

from __future__ import annotations

import difflib
import logging
import re
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from carapost.algorithms import params as _params
from carapost.algorithms.blobs import BlobParameters
from carapost.algorithms.cleanup import CleanupParameters
from carapost.algorithms.gapfill import CLEAN_UP, GAP_FILLING, GapFillParameters
from carapost.algorithms.init3d import Init3DParameters
from carapost.algorithms.labelling import LABEL_FROM_TEMPLATE, LabellingParameters
from carapost.algorithms.params import (
    BLOB,
    INITIALIZE_3D,
    INITIALIZE_FROM_ROM,
    TARGET_TRACKER,
    TRACKING,
    TRIANGULATION,
    check_value,
    format_value,
)
from carapost.algorithms.rom import RomParameters
from carapost.algorithms.stabilise import StabilizationParameters
from carapost.algorithms.target_track import TargetTrackerParameters
from carapost.algorithms.tracking import TrackingParameters
from carapost.algorithms.triangulation import TriangulationParameters

log = logging.getLogger(__name__)

__all__ = [
    "SECTIONS",
    "SPECS",
    "Properties",
    "PropertyError",
    "PropertySpec",
    "UnknownPropertyError",
    "PARAMETER_CLASSES",
    "spec",
    "specs_from_parameters",
    "specs_in_section",
]

# Section names, as displayed (display order is SECTIONS below). The algorithm sections
# (BLOB, INITIALIZE_3D, INITIALIZE_FROM_ROM, TRACKING, TRIANGULATION) are named in
# carapost.algorithms.params, beside the fields that fill them.
DISPLAY = "Display"
SELECTION = "Selection"
STABILIZATION = "Stabilization Parameters"
EXPORT = "Export"

#: Keys that older project files may hold but that are now user settings
#: (carapost.ui.settings.PREFERENCES): purely GUI preferences do not belong to a take.
#: Loading ignores them without a warning; the user's own setting applies instead. They
#: are not migrated into the user settings: the file may come from a colleague, and
#: opening it must not change how this user's views look. The Display section's rows
#: (point label visibility and font size) are all about the person looking, not the
#: take (see carapost.ui.settings.DISPLAY_PREFERENCES); the next save drops them.
MOVED_TO_USER_SETTINGS = frozenset({
    "point_labels_all",
    "point_labels_selected",
    "point_labels_preselected",
    "label_font_size",
    "show_version_check_dialog",
    "tracker_update_timeline_every_frame",
    "tracker_update_2d_view_every_frame",
})

#: Type names accepted in :attr:`PropertySpec.type` besides the Python types
#: ``bool``, ``int``, ``float`` and ``str``.
CHOICE = "choice"
COLOUR = "colour"

_COLOUR_RE = re.compile(r"^#[0-9a-fA-F]{6}$")
_TRUE_WORDS = {"true", "yes", "on", "1"}
_FALSE_WORDS = {"false", "no", "off", "0"}


class PropertyError(ValueError):
    """A property value or name was refused.

    The message names the parameter by its displayed label and states what is
    allowed, so it can be shown to the user as is.

    Attributes
    ----------
    key : str or None
        The property key concerned, when there is one.
    """

    def __init__(self, message: str, key: str | None = None) -> None:
        super().__init__(message)
        self.key = key


class UnknownPropertyError(PropertyError, KeyError):
    """A property key or section name that the registry does not know.

    It is both a :class:`PropertyError` (a ``ValueError``) and a ``KeyError``, so
    ``props["nope"]`` behaves like a mapping lookup.
    """

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


@dataclass(frozen=True)
class PropertySpec:
    """Declaration of one property.

    Parameters
    ----------
    section : str
        Section it is shown in (one of :data:`SECTIONS`).
    key : str
        Unique snake_case identifier used in code, the CLI and project files.
    label : str
        Name as displayed (the reference guide's name where it has one).
    type : type or str
        ``bool``, ``int``, ``float``, ``str``, ``"choice"`` (one of ``choices``) or
        ``"colour"`` (``"#rrggbb"``).
    default : Any
        Default value; must itself be valid.
    minimum, maximum : float or None
        Bounds for ``int`` and ``float`` properties (inclusive unless the flags below
        say otherwise).
    choices : tuple of str or None
        Allowed values of a ``"choice"`` property.
    unit : str
        Unit shown beside the value (``"px"``, ``"mm"``, ``"frames"``, ``"0-1"``...).
    help : str
        One-line description for tooltips and the docs.
    min_exclusive, max_exclusive : bool
        The bound itself is not allowed (``minimum=0, min_exclusive=True``: positive).
    """

    section: str
    key: str
    label: str
    type: type | str
    default: Any
    minimum: float | None = None
    maximum: float | None = None
    choices: tuple[str, ...] | None = None
    unit: str = ""
    help: str = ""
    min_exclusive: bool = False
    max_exclusive: bool = False

    @property
    def kind(self) -> str:
        """Type as a plain name: bool, int, float, string, choice or colour."""
        if isinstance(self.type, str):
            return self.type
        return {bool: "bool", int: "int", float: "float", str: "string"}[self.type]

    def range_text(self) -> str:
        """Allowed values in words, e.g. ``"between 0 and 1"`` (empty if unrestricted)."""
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        bounds = _params.range_text(self.minimum, self.maximum, self.min_exclusive,
                                    self.max_exclusive)
        if bounds:
            return bounds
        if self.kind == COLOUR:
            return "a colour '#rrggbb'"
        return ""

    def _refuse(self, value: Any, expected: str) -> PropertyError:
        return PropertyError(f"{self.label} must be {expected} (got {_params.shown(value)})",
                             self.key)

    def validate(self, value: Any) -> Any:
        """Check ``value`` and return it coerced to the property's type.

        Integers are accepted for float properties, integral floats for int
        properties and numpy scalars for both; a choice is matched ignoring case.

        Raises
        ------
        PropertyError
            If the value has the wrong type or lies outside the allowed range; the
            message names the label and the allowed range or choices.
        """
        if self.kind == COLOUR:
            if isinstance(value, str) and _COLOUR_RE.match(value):
                return value.lower()
            raise self._refuse(value, "a colour written '#rrggbb'")
        kind = self.type if isinstance(self.type, type) else str  # a choice is text
        try:  # the same check as the algorithm parameter classes make
            return check_value(value, self, kind, self.label)
        except ValueError as exc:
            raise PropertyError(str(exc), self.key) from None

    def parse(self, text: str) -> Any:
        """Convert command-line text (``"0.5"``, ``"true"``, ``"Y"``) and validate it.

        Raises
        ------
        PropertyError
            If the text does not read as a valid value.
        """
        kind = self.kind
        stripped = text.strip()
        if kind == "bool":
            word = stripped.lower()
            if word in _TRUE_WORDS:
                return True
            if word in _FALSE_WORDS:
                return False
            raise self._refuse(text, "true or false")
        if kind in ("int", "float"):
            try:
                number = float(stripped)
            except ValueError:
                raise self._refuse(text, f"a number {self.range_text()}".rstrip()) from None
            return self.validate(number)
        return self.validate(stripped if kind != "string" else text)


def _p(
    section: str,
    key: str,
    label: str,
    type_: type | str,
    default: Any,
    minimum: float | None = None,
    maximum: float | None = None,
    *,
    choices: tuple[str, ...] | None = None,
    unit: str = "",
    help: str = "",
) -> PropertySpec:
    return PropertySpec(section, key, label, type_, default, minimum, maximum, choices, unit, help)


#: The algorithm parameter classes whose property fields make up their sections, in
#: display order.
PARAMETER_CLASSES: tuple[type, ...] = (
    BlobParameters,
    Init3DParameters,
    RomParameters,
    TrackingParameters,
    TriangulationParameters,
    LabellingParameters,
    StabilizationParameters,
    TargetTrackerParameters,
    GapFillParameters,
    CleanupParameters,
)

_KINDS: dict[type, type] = {bool: bool, int: int, float: float, str: str}


def specs_from_parameters(cls: type) -> tuple[PropertySpec, ...]:
    """The property specs of a parameter dataclass, from its fields' metadata.

    Parameters
    ----------
    cls : dataclass type
        Fields declared with :func:`carapost.algorithms.params.param` and a section
        become properties (key, label, default, range, unit and help as declared; the
        type is the default's); other fields are skipped.

    Returns
    -------
    tuple of PropertySpec
        In field order.

    Examples
    --------
    >>> [s.label for s in specs_from_parameters(RomParameters)][:2]
    ['ROM Frame Index', 'ROM Face Point Tracking Distance']
    >>> spec("black_min_radius").range_text()
    'greater than 0 and at most 1000'
    """
    out = []
    for f, info in _params.property_fields(cls):
        type_: type | str = CHOICE if info.choices is not None else _KINDS[type(f.default)]
        assert info.section is not None and info.label is not None
        out.append(PropertySpec(
            info.section, info.key or f.name, info.label, type_, f.default,
            info.minimum, info.maximum, info.choices, info.unit, info.help,
            info.min_exclusive, info.max_exclusive))
    return tuple(out)


_ALGORITHM_SPECS: tuple[PropertySpec, ...] = tuple(
    s for cls in PARAMETER_CLASSES if cls is not StabilizationParameters
    for s in specs_from_parameters(cls)
    if s.section != TARGET_TRACKER)  # the Tracker pane's settings come last
# the Stabilization section comes after Gap-Filling, as in the guide
_STABILIZATION_SPECS = specs_from_parameters(StabilizationParameters)

_OURS_DEFAULT = " Default is our choice (the guide gives none)."

#: Every property, in display order within each section.
# fmt: off
SPECS: tuple[PropertySpec, ...] = (
    # --- Display: every row is a user setting now (MOVED_TO_USER_SETTINGS) -------------
    # --- Selection --------------------------------------------------------------------
    _p(SELECTION, "select_points", "Points", bool, True,
       help="Points can be picked in the 2D and 3D views."),
    _p(SELECTION, "select_detections", "Detections", bool, True,
       help="Detections (blobs) can be picked in the 2D and 3D views."),
    _p(SELECTION, "select_sensors", "Sensors", bool, True,
       help="Cameras can be picked in the 2D and 3D views."),
    _p(SELECTION, "select_sticks", "Sticks", bool, True,
       help="Sticks can be picked in the 2D and 3D views."),
    # --- Blob, Initialize 3D, Initialize From ROM, Tracking, Triangulation ----------
    *_ALGORITHM_SPECS,
    # --- Stabilization Parameters (StabilizationParameters, algorithms/stabilise.py) --
    *_STABILIZATION_SPECS,
    # --- Export (contents are ours: the guide names the section only) -----------------
    _p(EXPORT, "export_range", "Export Range", CHOICE, "active", choices=("active", "all"),
       help="Export the active range only or the whole take." + _OURS_DEFAULT),
    _p(EXPORT, "export_include_brim_points", "Include Brim Points", bool, False,
       help="Also write the brim markers to C3D/FBX." + _OURS_DEFAULT),
    _p(EXPORT, "export_stabilized", "Export Stabilized Coordinates", bool, False,
       help="Write stabilised positions (head motion removed) instead of raw tracked ones."
            + _OURS_DEFAULT),
    _p(EXPORT, "fbx_up_axis", "FBX Up Axis", CHOICE, "Y", choices=("Y", "Z"),
       help="Which axis points up in the FBX scene (Y suits MotionBuilder and Maya)."
            + _OURS_DEFAULT),
    _p(EXPORT, "fbx_include_cameras", "FBX Include Cameras", bool, True,
       help="Write the solved cameras (with their per-frame motion) into the FBX."
            + _OURS_DEFAULT),
    _p(EXPORT, "fbx_include_sticks", "FBX Include Sticks", bool, False,
       help="Write sticks between points into the FBX as line geometry." + _OURS_DEFAULT),
    # --- Target Tracker (Tracker pane settings) ---------------------------------------
    *specs_from_parameters(TargetTrackerParameters),
)
# fmt: on

#: Section names in display order.
SECTIONS: tuple[str, ...] = (
    SELECTION,
    BLOB,
    INITIALIZE_3D,
    INITIALIZE_FROM_ROM,
    TRACKING,
    TRIANGULATION,
    LABEL_FROM_TEMPLATE,
    GAP_FILLING,
    CLEAN_UP,
    STABILIZATION,
    EXPORT,
    TARGET_TRACKER,
)

_BY_KEY: dict[str, PropertySpec] = {s.key: s for s in SPECS}
_BY_SECTION: dict[str, tuple[PropertySpec, ...]] = {
    name: tuple(s for s in SPECS if s.section == name) for name in SECTIONS
}


def _check_registry() -> None:
    """Fail at import time if the table itself is inconsistent (a programming error)."""
    if len(_BY_KEY) != len(SPECS):
        raise RuntimeError("duplicate property keys in SPECS")
    for s in SPECS:
        if s.section not in _BY_SECTION:
            raise RuntimeError(f"property {s.key!r} is in unknown section {s.section!r}")
        if s.validate(s.default) != s.default:
            raise RuntimeError(f"default of {s.key!r} is not in canonical form")


_check_registry()


def _unknown_key(key: object) -> UnknownPropertyError:
    hint = difflib.get_close_matches(str(key), list(_BY_KEY), n=3)
    more = f"; did you mean {', '.join(hint)}?" if hint else ""
    return UnknownPropertyError(f"unknown property {key!r}{more}", key=str(key))


def spec(key: str) -> PropertySpec:
    """The :class:`PropertySpec` of ``key``.

    Raises
    ------
    UnknownPropertyError
        If no property has that key (the message suggests close keys).
    """
    try:
        return _BY_KEY[key]
    except (KeyError, TypeError):
        raise _unknown_key(key) from None


def specs_in_section(name: str) -> tuple[PropertySpec, ...]:
    """Specs of one section in display order.

    Raises
    ------
    UnknownPropertyError
        If ``name`` is not one of :data:`SECTIONS`.
    """
    try:
        return _BY_SECTION[name]
    except KeyError:
        raise UnknownPropertyError(
            f"unknown properties section {name!r}; sections are {', '.join(SECTIONS)}"
        ) from None


def defaults() -> dict[str, Any]:
    """Every key mapped to its default value."""
    return {s.key: s.default for s in SPECS}


_MISSING: Any = object()


class Properties:
    """The current value of every property, validated on every change.

    Parameters
    ----------
    values : mapping of str to Any, optional
        Initial values; keys not given take their defaults. Unknown keys or invalid
        values raise :class:`PropertyError` (use :meth:`from_dict` for lenient loading).
    on_change : callable, optional
        Called with the set of keys whose value really changed, once per
        :meth:`set`, :meth:`update` or :meth:`restore_defaults` call that changed
        anything. It may be replaced later through the ``on_change`` attribute.

    Notes
    -----
    Values are plain ``bool``, ``int``, ``float`` and ``str`` objects, so
    :meth:`to_dict` is JSON-safe as it stands.
    """

    __hash__ = None  # type: ignore[assignment]  # mutable

    def __init__(
        self,
        values: Mapping[str, Any] | None = None,
        on_change: Callable[[set[str]], None] | None = None,
    ) -> None:
        self._values: dict[str, Any] = defaults()
        self.on_change = on_change
        if values:
            self._values.update(self._validated(values))

    # ---- reading -----------------------------------------------------------------------
    def __getitem__(self, key: str) -> Any:
        try:
            return self._values[key]
        except (KeyError, TypeError):
            raise _unknown_key(key) from None

    def get(self, key: str, default: Any = _MISSING) -> Any:
        """Value of ``key``; ``default`` if given and ``key`` is unknown, else raise."""
        if key in self._values:
            return self._values[key]
        if default is not _MISSING:
            return default
        raise _unknown_key(key)

    def __contains__(self, key: object) -> bool:
        return key in self._values

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def keys(self) -> tuple[str, ...]:
        """All property keys in display order."""
        return tuple(self._values)

    def items(self) -> tuple[tuple[str, Any], ...]:
        """``(key, value)`` pairs in display order."""
        return tuple(self._values.items())

    def spec(self, key: str) -> PropertySpec:
        """The :class:`PropertySpec` of ``key``."""
        return spec(key)

    def section(self, name: str) -> dict[str, Any]:
        """Key -> value of one section, e.g. the parameters of an algorithm.

        ``props.section("Blob Parameters")`` gives the blob detector's keyword arguments.
        """
        return {s.key: self._values[s.key] for s in specs_in_section(name)}

    def non_defaults(self) -> dict[str, Any]:
        """Key -> value of the properties that differ from their default."""
        return {k: v for k, v in self._values.items() if v != _BY_KEY[k].default}

    def problems(self) -> list[str]:
        """Combinations of values that are each valid but make little sense together.

        Returns
        -------
        list of str
            One readable sentence per problem; empty when all is well. These are
            advisories for the user, not errors (the guide only recommends them).
        """
        v = self._values
        out = []
        for colour in ("white", "black"):
            low, high = v[f"{colour}_min_radius"], v[f"{colour}_max_radius"]
            if low > high:
                out.append(
                    f"{spec(f'{colour}_min_radius').label} ({format_value(low)}) is larger than "
                    f"{spec(f'{colour}_max_radius').label} ({format_value(high)}): "
                    "no blob can match"
                )
        if not (v["find_black_blobs"] or v["find_white_blobs"]):
            out.append("Neither Find Black Blobs nor Find White Blobs is set: no blob is found")
        elastic = v["face_point_max_elastic_prediction_distance"]
        if elastic > v["face_point_tracking_distance"]:
            out.append(
                "Face Point Max Elastic Prediction Distance "
                f"({format_value(elastic)}) should not exceed Face Point Tracking Distance "
                f"({format_value(v['face_point_tracking_distance'])})"
            )
        if not (v["use_forwards_prediction"] or v["use_backwards_prediction"]):
            out.append("Gap filling needs Use Forwards Prediction or Use Backwards Prediction")
        return out

    # ---- writing -----------------------------------------------------------------------
    def _validated(self, mapping: Mapping[str, Any]) -> dict[str, Any]:
        return {key: spec(key).validate(value) for key, value in mapping.items()}

    def _apply(self, new: Mapping[str, Any]) -> set[str]:
        changed = {k for k, value in new.items() if self._values[k] != value}
        for k in changed:
            self._values[k] = new[k]
        if changed and self.on_change is not None:
            self.on_change(changed)
        return changed

    def set(self, key: str, value: Any) -> None:
        """Validate and store one value; notify ``on_change`` only if it really changed.

        Raises
        ------
        PropertyError
            If ``key`` is unknown or ``value`` is not allowed (nothing changes).
        """
        self._apply({key: spec(key).validate(value)})

    def __setitem__(self, key: str, value: Any) -> None:
        self.set(key, value)

    def update(self, mapping: Mapping[str, Any]) -> set[str]:
        """Set several values at once, all or nothing.

        Every value is validated before any is stored, so one bad value leaves the
        properties untouched. ``on_change`` is called once with all changed keys.

        Returns
        -------
        set of str
            The keys whose value changed.
        """
        return self._apply(self._validated(mapping))

    def restore_defaults(self, section: str | None = None) -> dict[str, Any]:
        """Put every property (or one section's) back to its default.

        Parameters
        ----------
        section : str, optional
            Restrict the reset to this section.

        Returns
        -------
        dict
            The values before the reset (of the keys concerned), so that
            ``props.update(old)`` undoes it.
        """
        specs = SPECS if section is None else specs_in_section(section)
        old = {s.key: self._values[s.key] for s in specs}
        self._apply({s.key: s.default for s in specs})
        return old

    # ---- persistence -------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Key -> value for every property (JSON-safe plain values)."""
        return dict(self._values)

    @classmethod
    def from_dict(
        cls,
        d: Mapping[str, Any],
        on_change: Callable[[set[str]], None] | None = None,
    ) -> Properties:
        """Lenient loading, e.g. from a project file written by another version.

        Unknown keys are ignored and invalid values replaced by the default; each
        is reported with a logged warning naming the key. Missing keys take defaults.

        Raises
        ------
        PropertyError
            If ``d`` is not a mapping at all.
        """
        if not isinstance(d, Mapping):
            raise PropertyError(
                f"properties must be a mapping of key to value, not {type(d).__name__}"
            )
        good: dict[str, Any] = {}
        for key, value in d.items():
            if key in MOVED_TO_USER_SETTINGS:
                # a GUI preference saved by an older version: now a user setting
                log.debug("ignoring %r: it is a user setting now", key)
                continue
            if key not in _BY_KEY:
                log.warning("ignoring unknown property %r", key)
                continue
            try:
                good[key] = _BY_KEY[key].validate(value)
            except PropertyError as exc:
                log.warning("property %r reset to its default: %s", key, exc)
        return cls(good, on_change=on_change)

    def copy(self) -> Properties:
        """An independent copy of the values (without the ``on_change`` callback)."""
        return Properties(self._values)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Properties):
            return NotImplemented
        return self._values == other._values

    def __repr__(self) -> str:
        changed = self.non_defaults()
        return f"Properties({changed!r})" if changed else "Properties()"
