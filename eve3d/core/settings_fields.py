"""How a settings class is declared and checked: :func:`setting` gives a field its default
and bounds, :class:`Checked` checks them whenever one is made, :func:`from_mapping` reads a
config section strictly (an unknown key or a value of the wrong type is an error naming its
full key path), and :func:`keys` reads each field's documentation, the string under it in
its module's source, for the CLI's flags and config/README.md's tables. The classes
themselves are in :mod:`eve3d.core.settings`."""
from __future__ import annotations

import copy
import dataclasses
import functools
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from eve3d.core.errors import Eve3dError


def setting(default: Any = None, *, factory: Any = None, ge: float | None = None, gt: float | None = None,
            le: float | None = None, choices: Any = None, nonzero: bool = False) -> Any:
    """A settings field: its default (or ``factory`` for a nested settings class) and its
    bounds, checked by :func:`check` (``ge`` ≥, ``gt`` >, ``le`` ≤, ``choices``, ``nonzero``)."""
    bounds = {k: v for k, v in dict(ge=ge, gt=gt, le=le, choices=choices).items() if v is not None}
    if nonzero:
        bounds["nonzero"] = True
    if factory is not None:
        return field(default_factory=factory, metadata=bounds)
    return field(default=default, metadata=bounds)


def _kind(annotation: str) -> tuple[str, bool]:
    """The value kind a field's annotation asks for (bool, int, float, str, tuple, mapping)
    and whether None is allowed."""
    optional = "None" in annotation
    for kind in ("tuple", "dict", "bool", "float", "int", "str"):
        if annotation.startswith(kind) or f"| {kind}" in annotation or f"{kind} |" in annotation:
            return kind, optional
    return "any", optional


_KIND_WORDS = {"bool": "true or false", "int": "an integer", "float": "a number", "str": "a string",
               "tuple": "a list of numbers", "dict": "a mapping", "any": "a value"}


def _expected(kind: str, bounds: dict) -> str:
    if "choices" in bounds:
        return "one of " + ", ".join(map(str, bounds["choices"]))
    text = _KIND_WORDS[kind]
    limits = [f"≥ {bounds['ge']:g}" if "ge" in bounds else "", f"> {bounds['gt']:g}" if "gt" in bounds else "",
              f"≤ {bounds['le']:g}" if "le" in bounds else "", "not 0" if bounds.get("nonzero") else ""]
    limits = [x for x in limits if x]
    return text + (" " + " and ".join(limits) if limits else "")


def _coerce(kind: str, value: Any) -> tuple[bool, Any]:
    """Whether ``value`` is of ``kind`` (an integral float counts as an int, an int as a
    float, a list as a tuple), and the value converted to it."""
    if kind == "bool":
        return isinstance(value, bool), value
    if kind in ("int", "float"):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return False, value
        if kind == "int":
            return float(value).is_integer(), int(value) if float(value).is_integer() else value
        return True, float(value)
    if kind == "tuple":
        ok = isinstance(value, (list, tuple)) and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                      for v in value)
        return ok, tuple(value) if ok else value
    if kind == "dict":
        return isinstance(value, Mapping), value
    if kind == "str":
        return isinstance(value, str), value
    return True, value


def _in_bounds(value: Any, bounds: dict) -> bool:
    if "choices" in bounds:
        return value in bounds["choices"]
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return True
    return (("ge" not in bounds or value >= bounds["ge"]) and ("gt" not in bounds or value > bounds["gt"])
            and ("le" not in bounds or value <= bounds["le"]) and not (bounds.get("nonzero") and value == 0))


def check(obj: Any, where: str) -> None:
    """Every field of a settings object against its kind and bounds, each value converted to
    its kind on the way (an integral float to an int, a list to a tuple); the error names
    ``where.field``, what is expected and what was given."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            continue
        kind, optional = _kind(str(f.type))
        if value is None and optional:
            continue
        ok, converted = _coerce(kind, value)
        if not (ok and _in_bounds(converted, f.metadata)):
            raise Eve3dError(f"{where}.{f.name}: expected {_expected(kind, f.metadata)}, got {value!r}")
        setattr(obj, f.name, converted)


def from_mapping(cls: type, values: Mapping, where: str) -> Any:
    """``cls`` from a config section, strictly: an unknown key, a value of the wrong kind or
    out of bounds is an error that names its full key path (``stereo.mv_views: expected an
    integer ≥ 1, got 0``). Nested settings classes are built from nested mappings."""
    if not isinstance(values, Mapping):
        raise Eve3dError(f"{where}: expected a mapping, got {values!r}")
    known = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise Eve3dError(f"{where}: unknown key(s) {', '.join(map(str, unknown))} (known: {', '.join(sorted(known))})")
    kwargs = {}
    for name, value in values.items():
        nested = known[name].default_factory  # a settings class, for a nested section
        is_section = isinstance(nested, type) and dataclasses.is_dataclass(nested)
        kwargs[name] = from_mapping(nested, value, f"{where}.{name}") if is_section else value
    return _made(cls, kwargs, where)


def flag(name: str) -> str:
    """The command-line flag of a settings field or a stage's input (``min_views`` →
    ``--min-views``)."""
    return "--" + name.replace("_", "-")


def pick(cls: type, settings: Any) -> Any:
    """The ``cls`` part of a settings object whose class derives from ``cls`` (a section's
    settings read by one stage: the baseline of :class:`StereoSettings`)."""
    return cls(**{f.name: getattr(settings, f.name) for f in dataclasses.fields(cls)})


def _made(cls: type, kwargs: dict, where: str) -> Any:
    """``cls(**kwargs)``, with a cross-field check's error re-addressed to ``where``."""
    try:
        return cls(**kwargs)
    except Eve3dError as e:
        section = getattr(cls, "SECTION", "")
        message = str(e)
        if section and message.startswith(section + ".") and where != section:
            message = where + message[len(section):]
        raise Eve3dError(message) from None


@dataclass(frozen=True)
class Key:
    """One settings field as the CLI and the key tables of config/README.md present it."""

    name: str
    kind: str
    """bool, int, float, str, tuple, dict or any (:func:`_kind`)."""
    optional: bool
    default: Any
    bounds: dict
    doc: str
    """The field's docstring (its first sentence is the CLI help), or ""."""

    @property
    def expected(self) -> str:
        return _expected(self.kind, self.bounds) + (" or null" if self.optional else "")


@functools.cache
def _field_docs(source: str) -> dict[tuple[str, str], str]:
    """(class, field) → the string literal under the field in the module file ``source``:
    the field docstrings that Python itself drops."""
    import ast

    docs = {}
    for node in ast.parse(Path(source).read_text()).body:
        if isinstance(node, ast.ClassDef):
            for a, b in zip(node.body, node.body[1:]):
                if (isinstance(a, ast.AnnAssign) and isinstance(a.target, ast.Name) and isinstance(b, ast.Expr)
                        and isinstance(b.value, ast.Constant) and isinstance(b.value.value, str)):
                    docs[node.name, a.target.id] = " ".join(b.value.value.split())
    return docs


def keys(cls: type) -> list[Key]:
    """The fields of a settings class (nested sections left out) with kind, default, bounds
    and documentation; a field's docstring is looked up along the class's bases."""
    docs = {}
    for c in reversed(cls.__mro__):  # a class's own docstring over its bases'
        source = getattr(sys.modules.get(c.__module__), "__file__", None)
        docs.update(_field_docs(source) if source and source.endswith(".py") else {})
    out = []
    for f in dataclasses.fields(cls):
        if f.default is dataclasses.MISSING:
            continue  # a nested section (default_factory)
        kind, optional = _kind(str(f.type))
        doc = next((docs[c.__name__, f.name] for c in cls.__mro__ if (c.__name__, f.name) in docs), "")
        out.append(Key(f.name, kind, optional, f.default, dict(f.metadata), doc))
    return out


def sections_of(cls: type) -> dict[str, type]:
    """The nested settings sections of ``cls`` (``lr``, ``densify``, ``onnx``) by field name."""
    return {f.name: f.default_factory for f in dataclasses.fields(cls)
            if isinstance(f.default_factory, type) and dataclasses.is_dataclass(f.default_factory)}


class Checked:
    """Base of every settings class: bounds are checked whenever one is made, and errors
    name ``SECTION.key`` (the config section it is read from)."""

    SECTION: ClassVar[str] = ""

    def __post_init__(self) -> None:
        check(self, self.SECTION)


def deep_merge(base: dict, override: dict) -> dict:
    """``override`` on top of ``base``, recursively for nested mappings."""
    out = copy.deepcopy(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out
