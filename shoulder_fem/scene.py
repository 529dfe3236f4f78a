"""Scene descriptions: TOML files with parameters (value + unit + bounds) and mesh levels.

A scene file looks like::

    name = "spinning-bar"
    family = "driven-body"
    summary = "one line for `shoulder-fem scenes`"

    [parameters.youngs_modulus]
    value = 15
    unit = "GPa"
    gt = 0            # bounds in the same unit as value
    doc = "Young's modulus of the bar"

    [levels.coarse]
    n_axial = 12

Values are converted to SI on load. ``--set key=value`` overrides accept a bare number (read in
the parameter's SI unit) or a number with a unit of the same kind (``--set spin_rate=600rpm``;
any unit pint reads, :mod:`shoulder_fem.units`).
Every error names the file (or ``--set``), the key, the value and the unit.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

from shoulder_fem.units import UnitError, si_unit, to_si

SCENE_DIR = Path(__file__).parent / "scenes"
LEVELS = ("coarse", "medium", "paper", "fine")

_BOUNDS = {
    "gt": (">", lambda v, b: v > b),
    "ge": (">=", lambda v, b: v >= b),
    "lt": ("<", lambda v, b: v < b),
    "le": ("<=", lambda v, b: v <= b),
}
_NUMBER_WITH_UNIT = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*?)\s*$")


class SceneError(ValueError):
    """A scene file, a scene name or an override is wrong; the message says where and why."""


@dataclass(frozen=True)
class Parameter:
    """One scene parameter, stored in SI.

    Attributes:
        name: key in the scene file.
        value: SI value (float), or int / bool for counts and switches.
        unit: SI unit ("1" for dimensionless, "" for counts and switches).
        file_unit: the unit the scene file used (for messages and bounds).
        bounds: {"gt"|"ge"|"lt"|"le": SI value}.
        doc: one line saying what it is.
    """

    name: str
    value: float | int | bool
    unit: str
    file_unit: str
    bounds: dict = field(default_factory=dict)
    doc: str = ""
    choices: tuple[str, ...] = ()

    def checked(self, value, where: str) -> Parameter:
        """Return a copy holding ``value`` (SI) after checking its type and bounds."""
        if isinstance(self.value, str):
            if not isinstance(value, str):
                raise SceneError(f"{where}: {self.name} = {value!r}: expected text")
            if self.choices and value not in self.choices:
                raise SceneError(
                    f"{where}: {self.name} = {value!r}: expected one of {', '.join(self.choices)}"
                )
            return replace(self, value=value)
        if isinstance(self.value, bool):
            if not isinstance(value, bool):
                raise SceneError(f"{where}: {self.name} = {value!r}: expected true or false")
        elif isinstance(self.value, int):
            if isinstance(value, bool) or not float(value).is_integer():
                raise SceneError(f"{where}: {self.name} = {value!r}: expected an integer")
            value = int(value)
        else:
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise SceneError(f"{where}: {self.name} = {value!r}: expected a number")
            value = float(value)
            if not math.isfinite(value):
                raise SceneError(f"{where}: {self.name} = {value} {self.unit}: must be finite")
        for key, bound in self.bounds.items():
            symbol, ok = _BOUNDS[key]
            if not ok(value, bound):
                raise SceneError(
                    f"{where}: {self.name} = {self._show(value)}: must be {symbol} "
                    f"{self._show(bound)}"
                )
        return replace(self, value=value)

    def described(self) -> tuple[str, str]:
        """(value, bounds) as a reader sets them: in the scene file's unit, e.g. ``60 deg``."""
        if self.choices:
            return str(self.value), "one of " + ", ".join(self.choices)
        if isinstance(self.value, str):  # free text (a path)
            return repr(self.value), "text"
        if isinstance(self.value, bool) or not isinstance(self.value, float):
            return str(self.value).lower(), _bounds_text(self.bounds, 1.0, "")
        unit = self.file_unit or self.unit
        unit = "" if unit == "1" else unit  # dimensionless: the number alone
        scale = si_unit(self.file_unit)[1] if self.file_unit else 1.0
        return f"{self.value / scale:g} {unit}".strip(), _bounds_text(self.bounds, scale, unit)

    def _show(self, si_value: float) -> str:
        """``si_value`` with its SI unit, and in the file's unit when that differs."""
        unit = "" if self.unit == "1" else self.unit
        text = f"{si_value:g} {unit}".strip()
        if self.file_unit and self.file_unit != self.unit:
            text += f" ({si_value / si_unit(self.file_unit)[1]:g} {self.file_unit})"
        return text


def _bounds_text(bounds: dict, scale: float, unit: str) -> str:
    """``> 0 mm, <= 90 deg``-like text of SI ``bounds`` in a unit of ``scale`` SI units."""
    return ", ".join(
        f"{_BOUNDS[key][0]} {f'{bound / scale:g} {unit}'.strip()}" for key, bound in bounds.items()
    )


@dataclass(frozen=True)
class Scene:
    """A scene: its family (which model builder runs it), parameters (SI) and mesh levels."""

    name: str
    family: str
    summary: str
    parameters: dict[str, Parameter]
    levels: dict[str, dict]
    source: str
    default_level: str = "coarse"
    overridden: tuple[str, ...] = ()

    def __getitem__(self, key: str):
        """SI value of parameter ``key``."""
        try:
            return self.parameters[key].value
        except KeyError:
            raise SceneError(
                f"{self.source}: scene '{self.name}' has no parameter '{key}' "
                f"(known: {', '.join(sorted(self.parameters))})"
            ) from None

    def values(self) -> dict:
        """All parameter values in SI."""
        return {k: p.value for k, p in self.parameters.items()}

    def units(self) -> dict:
        """All parameter units (SI)."""
        return {k: p.unit for k, p in self.parameters.items()}

    def with_values(self, where: str = "override", **values) -> Scene:
        """A copy with parameters changed, checked like the file's values.

        A value is a number in SI (``final_angle=math.radians(20)``) or a string as ``--set``
        takes it, with or without a unit (``final_angle="20deg"``, ``head_radius="25 mm"``).
        """
        params = dict(self.parameters)
        for key, value in values.items():
            if key not in params:
                raise SceneError(
                    f"{where}: unknown parameter '{key}' for scene '{self.name}' "
                    f"(known: {', '.join(sorted(params))})"
                )
            if isinstance(value, str) and not isinstance(params[key].value, str):
                value = _parse_value(params[key], value, f"{where} {key}={value}")
            params[key] = params[key].checked(value, where)
        overridden = tuple(dict.fromkeys(self.overridden + tuple(values)))
        return replace(self, parameters=params, overridden=overridden)

    def where(self, *keys: str) -> str:
        """Where parameters ``keys`` came from, for messages: the file and/or the overrides."""
        changed = [k for k in keys if k in self.overridden]
        if not changed:
            return self.source
        return f"{self.source} with override(s) {', '.join(changed)}"

    def with_overrides(self, assignments: list[str]) -> Scene:
        """Apply ``key=value`` strings (the CLI's ``--set``)."""
        values = {}
        for text in assignments:
            key, sep, raw = text.partition("=")
            key = key.strip()
            where = f"--set {text}"
            if not sep or not key:
                raise SceneError(f"{where}: expected key=value")
            if key not in self.parameters:
                raise SceneError(
                    f"{where}: unknown parameter '{key}' for scene '{self.name}' "
                    f"(known: {', '.join(sorted(self.parameters))})"
                )
            values[key] = _parse_value(self.parameters[key], raw, where)
        scene = self
        for key, value in values.items():
            scene = scene.with_values(where=f"--set {key}", **{key: value})
        return scene

    def level(self, level: str | None) -> dict:
        """Mesh/discretisation settings of ``level`` (default: the scene's default level)."""
        level = level or self.default_level
        if level not in self.levels:
            raise SceneError(
                f"{self.source}: scene '{self.name}' has no level '{level}' "
                f"(known: {', '.join(self.levels)})"
            )
        return dict(self.levels[level])


def _parse_value(param: Parameter, raw: str, where: str):
    raw = raw.strip()
    if isinstance(param.value, str):
        return raw
    if isinstance(param.value, bool):
        if raw.lower() in ("true", "1", "yes", "on"):
            return True
        if raw.lower() in ("false", "0", "no", "off"):
            return False
        raise SceneError(f"{where}: expected true or false")
    match = _NUMBER_WITH_UNIT.match(raw)
    if not match:
        raise SceneError(f"{where}: '{raw}' is not a number (optionally with a unit)")
    number, unit = float(match.group(1)), match.group(2)
    if not unit:
        return number
    if not param.unit:
        raise SceneError(f"{where}: {param.name} is a count or a switch: it takes no unit")
    try:
        return to_si(number, unit, param.unit, param.name)
    except UnitError as err:
        raise SceneError(f"{where}: {err}") from None


def available_scenes() -> dict[str, Path]:
    """Built-in scene names → files."""
    return {p.stem: p for p in sorted(SCENE_DIR.glob("*.toml"))}


def load_scene(name_or_path: str | Path) -> Scene:
    """Load a built-in scene by name, or a scene file by path."""
    path = Path(name_or_path)
    if path.suffix != ".toml":
        scenes = available_scenes()
        if str(name_or_path) not in scenes:
            raise SceneError(
                f"unknown scene '{name_or_path}' (known: {', '.join(scenes) or 'none'}; "
                "or give a path to a .toml file)"
            )
        path = scenes[str(name_or_path)]
    if not path.is_file():
        raise SceneError(f"scene file {path} does not exist")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise SceneError(f"{path}: not valid TOML: {err}") from None
    return _scene_from_dict(data, str(path))


def _scene_from_dict(data: dict, source: str) -> Scene:
    for key in ("name", "family", "parameters", "levels"):
        if key not in data:
            raise SceneError(f"{source}: missing top-level key '{key}'")
    params = {}
    for name, spec in data["parameters"].items():
        params[name] = _parameter_from_spec(name, spec, source)
    levels = data["levels"]
    if not isinstance(levels, dict) or not levels:
        raise SceneError(f"{source}: [levels] must define at least one level")
    for level in levels:
        if level not in LEVELS:
            raise SceneError(f"{source}: level '{level}' is not one of {', '.join(LEVELS)}")
    default_level = data.get("default_level", "coarse")
    if default_level not in levels:
        raise SceneError(f"{source}: default_level '{default_level}' is not defined in [levels]")
    return Scene(
        name=data["name"],
        family=data["family"],
        summary=data.get("summary", ""),
        parameters=params,
        levels=levels,
        source=source,
        default_level=default_level,
    )


def _parameter_from_spec(name: str, spec, source: str) -> Parameter:
    where = f"{source}: parameters.{name}"
    if not isinstance(spec, dict) or "value" not in spec:
        raise SceneError(f"{where}: expected a table with at least 'value' (and 'unit')")
    value = spec["value"]
    unknown = set(spec) - {"value", "unit", "doc", "choices", *_BOUNDS}
    if unknown:
        raise SceneError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
    if isinstance(value, str):
        choices = spec.get("choices", [])  # none: free text (e.g. a path)
        if not isinstance(choices, list) or not all(isinstance(c, str) for c in choices):
            raise SceneError(f"{where}: 'choices' of a text value must be a list of strings")
        proto = Parameter(name, value, "", "", {}, spec.get("doc", ""), tuple(choices))
        return proto.checked(value, where)
    if isinstance(value, bool) or (isinstance(value, int) and "unit" not in spec):
        file_unit, si, factor = "", "", 1
    else:
        file_unit = spec.get("unit")
        if file_unit is None:
            raise SceneError(f'{where}: value {value} has no unit (use unit = "1" if none)')
        try:
            si, factor = si_unit(file_unit)
        except UnitError as err:
            raise SceneError(f"{where}: {err}") from None
        if not isinstance(value, int | float):
            raise SceneError(f"{where}: value {value!r} {file_unit} is not a number")
        value = float(value) * factor
    bounds = {k: spec[k] * factor for k in _BOUNDS if k in spec}
    proto = Parameter(name, value, si, file_unit, bounds, spec.get("doc", ""))
    return proto.checked(value, where)
