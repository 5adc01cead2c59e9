"""Configuration files of every layer: YAML 1.2 text -> typed dataclass trees, dotted overrides.

One loader for all configuration in the project (the SNAN presets ``configs/snan-*.yaml``, the
HIL task ``configs/hil-6x6.yaml``, the device ``configs/device-ysz.yaml`` that the emulator's
chip is made of, the paper targets of ``snan-hil readings`` ``configs/paper-targets.yaml``, the
training config stored in a weights file). A configuration is a tree of plain (stdlib, frozen
or not) dataclasses; this module knows nothing of any particular one. A base module like
:mod:`snan_hil.common.errors` and :mod:`snan_hil.files.atomicio`: every layer, ``protocol`` and
``crossbar_model`` included, may import it.

API (``T`` a dataclass type; ``where`` prefixes error messages, e.g. a file name):

* :func:`read_yaml` / :func:`parse_yaml`: a file / text -> plain tree (dict, list, str, int,
  float, bool, None), read as YAML 1.2.
* :func:`from_tree` ``(cls, tree, base=None)``: build a ``cls`` from a mapping; keys not given
  take ``base``'s values (or the dataclass defaults). Nested dataclass fields take nested
  mappings, merged into the base's section.
* :func:`apply` ``(obj, {"section.key": value})``: a copy of ``obj`` with dotted keys set to
  *typed* values (no text round trip); a mapping value on a section key is merged into it.
* :func:`parse_assignments` ``(cls, ["section.key=text", ...])``: the CLI's ``--set`` texts ->
  ``{"section.key": typed value}``, each text read for its field's type (below);
  :func:`check_keys` checks a mapping of dotted keys to typed values the same way (e.g. one
  stored in a file) without building a ``cls``.
* :func:`load` = read_yaml + from_tree + apply + parse_assignments; :func:`to_tree` (plain
  dict), :func:`field_type`, :func:`differences` (dotted keys where two trees differ).
* :func:`field_default` ``(cls, "section.key")``: a field's default as the class declares it
  (the CLI's option defaults come from here, never restated as literals).
* :func:`check_bounds` ``(obj)``: the ``Annotated`` bounds of every field of a dataclass tree
  built in code (a config class's ``__post_init__`` calls it, so ``WVConfig(tolerance=-1)``
  fails as a file or ``--set`` would, naming the field and the bound).
* :func:`check_value` ``(cls, dotted, value, key=...)``: one value (a command-line option that
  stands for a config field) against that field's type and bounds.

Rules, for files and ``--set`` alike:

* Numbers as YAML 1.2 reads them: ``1e-3``, ``1.0e-5``, ``1e3`` are floats; ``010`` is decimal
  10 (never octal 8; octal is ``0o10``); ``1:40`` is the text "1:40" (never sexagesimal 100), so
  a number field refuses it; ``off``/``yes`` are text, booleans are ``true``/``false``. A
  ``%YAML 1.1`` directive is refused (it would switch the reader back to YAML 1.1). Duplicate
  keys are refused.
* Leaf values are checked strictly against the field's type hint: an ``int`` field takes only
  integers (not ``2.5``, ``"3"`` or ``true``); a ``float`` field takes integers and floats, finite
  only; ``bool`` only ``true``/``false``; a ``Literal`` one of its values; ``str`` only text.
  ``Annotated`` bounds (``annotated_types.Ge``, ``Gt``, ``Interval``, ``pydantic.Field(gt=...)``)
  are checked and named: a config class declares a field's bounds beside it
  (``tau_m_ms: Annotated[float, Gt(0)] = 150.0``), its unit in the name or the comment.
  A ``tuple`` field takes a YAML list.
* ``--set KEY=TEXT``: for a text field (``str`` or a ``Literal`` of texts) TEXT is the value as
  written (``stdp.mode=off`` is "off"); for any other field TEXT is read as one YAML 1.2 value
  (a number, ``true``, a flow mapping ``{rows: 4, cols: 4}`` for a section) and then checked as
  above.
* Unknown keys are named together with the keys that exist at that level; cross-field checks of
  a config class live in its ``__post_init__`` (a ``ValueError`` or
  :class:`~snan_hil.common.errors.UserError` there becomes a :class:`ConfigError` naming ``where``).
  Every error is one line (:class:`ConfigError`, a ``UserError``: exit code 2 in the CLI).

Why these libraries (issue 14): PyYAML, used before, implements YAML 1.1 (``1e-3`` is text,
``010`` octal 8, ``1:40`` sexagesimal 100, ``off`` false); ``ruamel.yaml`` in its safe, pure
mode reads YAML 1.2 and refuses duplicate keys. Leaf values are validated by pydantic v2's
``TypeAdapter`` in strict mode, the most used typed-validation library (strict numbers,
``Literal``, ``Annotated`` bounds, structured error types we turn into one-line messages). The
config classes stay plain dataclasses (no pydantic base classes or per-class config), so the
walk over the dataclass fields -- unknown keys, defaults, merge into a base -- is the ~60 lines
here. cattrs and dacite were not chosen: their conversions are lenient by default (cattrs
structures ``2.5`` into an ``int`` field as 2) or need a per-type hook for every rule above.
"""

from __future__ import annotations

import dataclasses
import functools
import numbers
import os
import re
import reprlib
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar, get_args, get_origin

from snan_hil.common.errors import UserError

__all__ = ["ConfigError", "parse_yaml", "read_yaml", "from_tree", "apply", "check_keys",
           "parse_assignments", "load", "to_tree", "field_type", "differences", "check_bounds",
           "field_default", "check_value",
           "MISSING"]

T = TypeVar("T")


class ConfigError(UserError):
    """A configuration file, value or override is invalid (one line, exit code 2)."""


class _Missing:
    def __repr__(self) -> str:
        return "(absent)"


MISSING: Any = _Missing()
"""Stands for a key one side of :func:`differences` does not have."""


# ---- YAML 1.2 ---------------------------------------------------------------------------------
_DIRECTIVE = re.compile(r"^%YAML[ \t]+(\S+)", re.MULTILINE)


MAX_VALUES = 100_000
"""Most values (mapping keys, values, list items, aliases counted as what they expand to) a
YAML configuration may hold: the largest of the project's is a few hundred; a file of nested
aliases (an "alias bomb") expands past it in a few hundred bytes and is refused before it is
walked."""

_SHOWN = reprlib.Repr()
_SHOWN.maxstring, _SHOWN.maxother, _SHOWN.maxlevel = 40, 40, 2
_SHOWN.maxlist = _SHOWN.maxtuple = 6
_SHOWN.maxdict = 4


def _show(value: Any) -> str:
    """``repr`` of a value for an error message, cut to about 80 characters (a value from a
    file can be as large as the file, or larger once its aliases are expanded)."""
    return _SHOWN.repr(value)


def _expanded_size(tree: Any, where: str) -> int:
    """How many values ``tree`` holds once its aliases are expanded (a node reached twice
    counts twice), computed once per distinct node; ConfigError when it passes
    :data:`MAX_VALUES` or an alias refers to itself."""
    sizes: dict[int, int] = {}
    active: set[int] = set()

    def size(node: Any) -> int:
        if not isinstance(node, (dict, list)):
            return 1
        key = id(node)
        if key in sizes:
            return sizes[key]
        if key in active:
            raise ConfigError(f"{where}: a YAML alias refers to the value it is part of; write "
                              "the value out")
        active.add(key)
        items = (v for kv in node.items() for v in kv) if isinstance(node, dict) else node
        total = 1
        for item in items:
            total += size(item)
            if total > MAX_VALUES:
                raise ConfigError(f"{where}: more than {MAX_VALUES:,} values once its YAML "
                                  "aliases are expanded; a configuration holds a few hundred: "
                                  "write the values out or nest fewer aliases")
        active.discard(key)
        sizes[key] = total
        return total

    return size(tree)


def parse_yaml(text: str, where: str = "<text>") -> Any:
    """Read one YAML 1.2 document (safe: plain dicts, lists, str, int, float, bool, None).

    Raises :class:`ConfigError` ("``where`` is not valid YAML (line N: problem)") on a syntax
    error, a duplicate key, several documents, a tag of a Python object, or a ``%YAML``
    directive other than 1.2.
    """
    from ruamel.yaml import YAML          # on first use (see _strict_config)
    from ruamel.yaml.error import YAMLError

    m = _DIRECTIVE.search(text)
    if m and m.group(1) != "1.2":
        raise ConfigError(f"{where}: '%YAML {m.group(1)}' is not read; this project reads "
                          "YAML 1.2 (remove the %YAML line)")
    yaml = YAML(typ="safe", pure=True)
    yaml.version = (1, 2)
    try:
        tree = yaml.load(text)
    except YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        at = f"line {mark.line + 1}: " if mark is not None else ""
        raise ConfigError(f"{where} is not valid YAML ({at}{problem})") from None
    _expanded_size(tree, where)
    return tree


def read_yaml(path: str | os.PathLike | Any, *, what: str = "config file") -> Any:
    """Read a YAML 1.2 file (a path, or an ``importlib.resources`` Traversable).

    Raises :class:`ConfigError` if it is missing, unreadable or not valid YAML.
    """
    p = Path(path) if isinstance(path, (str, os.PathLike)) else path
    if not p.is_file():
        why = "is a folder; give a YAML file" if p.is_dir() else "no such file"
        raise ConfigError(f"cannot read {what} {path}: {why}")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc)
        raise ConfigError(f"cannot read {what} {path}: {reason}") from None
    return parse_yaml(text, f"{what} {path}")


# ---- the dataclass tree -------------------------------------------------------------------
def _is_config_class(hint: Any) -> bool:
    return isinstance(hint, type) and dataclasses.is_dataclass(hint)


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    """The field type hints of dataclass ``cls`` (resolved once per class)."""
    hints = _HINTS.get(cls)
    if hints is None:
        hints = _HINTS[cls] = typing.get_type_hints(cls, include_extras=True)
    return hints


def _init_fields(cls: type) -> list[dataclasses.Field]:
    return [f for f in dataclasses.fields(cls) if f.init]


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def _prefix(where: str) -> str:
    return f"{where}: " if where else ""


def _unknown(cls: type, path: str, name: Any, where: str,
             renamed: Mapping[str, str]) -> ConfigError:
    key = _join(path, str(name))
    if key in renamed:
        return ConfigError(f"{_prefix(where)}config key {key} is gone: {renamed[key]}")
    known = ", ".join(sorted(f.name for f in _init_fields(cls)))
    return ConfigError(f"{_prefix(where)}unknown config key {key} (known"
                       f"{' in ' + path if path else ''}: {known})")


def _resolve(cls: type, dotted: str, where: str = "",
             renamed: Mapping[str, str] = {}) -> tuple[list[str], Any]:
    """Split ``dotted`` into field names and return them with the last field's type hint."""
    parts = [p.strip() for p in dotted.split(".")]
    if not all(parts):
        raise ConfigError(f"{_prefix(where)}config key {_show(dotted)} is not a dotted key like "
                          "section.key")
    hint: Any = cls
    for i, part in enumerate(parts):
        path = ".".join(parts[:i])
        if not _is_config_class(hint):
            raise ConfigError(f"{_prefix(where)}unknown config key {dotted} ({path} is a value, "
                              "not a section)")
        if part not in {f.name for f in _init_fields(hint)}:
            raise _unknown(hint, path, part, where, renamed)
        hint = _hints(hint)[part]
    return parts, hint


def field_type(cls: type, dotted: str) -> Any:
    """The type hint of the field at ``dotted`` (e.g. ``"astro.a"``) of dataclass ``cls``."""
    return _resolve(cls, dotted)[1]


def field_default(cls: type, dotted: str) -> Any:
    """The default of the field at ``dotted`` of dataclass ``cls`` (``default_factory``
    called; a section's default is followed into it), without building a ``cls``.
    Raises :class:`ConfigError` for an unknown key or a field without a default."""
    parts, _hint = _resolve(cls, dotted)
    f = next(f for f in _init_fields(cls) if f.name == parts[0])
    if f.default is not dataclasses.MISSING:
        value: Any = f.default
    elif f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    else:
        raise ConfigError(f"config key {dotted} has no default")
    for part in parts[1:]:                  # into the section's default
        value = getattr(value, part)
    return value


def check_value(cls: type, dotted: str, value: Any, *, key: str | None = None) -> Any:
    """``value`` checked against the type and ``Annotated`` bounds of the field at ``dotted``
    of dataclass ``cls`` (for a command-line option that stands for that field), converted as
    the loader converts it; :class:`ConfigError` ``"KEY: must be <= 3600.0, got 1e+308"``
    (``key``: the option's name, default ``dotted``) otherwise."""
    return _leaf(_resolve(cls, dotted)[1], value, key or dotted, "")


_STRICT: Any = None


def _strict_config() -> Any:
    global _STRICT
    if _STRICT is None:
        # pydantic, ruamel.yaml, annotated_types: imported on first use here and below (every
        # layer imports this base module; ~0.15 s)
        from pydantic import ConfigDict
        _STRICT = ConfigDict(strict=True, allow_inf_nan=False)
    return _STRICT


@functools.cache
def _adapter_cached(hint: Any) -> Any:
    from pydantic import TypeAdapter      # on first use (see _strict_config)
    return TypeAdapter(hint, config=_strict_config())


def _adapter(hint: Any) -> Any:
    try:
        return _adapter_cached(hint)
    except TypeError:                       # an unhashable hint (Annotated with a FieldInfo)
        from pydantic import TypeAdapter  # on first use (see _strict_config)
        return TypeAdapter(hint, config=_strict_config())


def _bare(hint: Any) -> Any:
    """``hint`` without ``Annotated``."""
    while get_origin(hint) is typing.Annotated:
        hint = get_args(hint)[0]
    return hint


def _takes_text(hint: Any) -> bool:
    """A field whose ``--set`` text is its value as written (str, or a Literal of texts)."""
    bare = _bare(hint)
    if bare is str:
        return True
    return get_origin(bare) is Literal and all(isinstance(a, str) for a in get_args(bare))


_PHRASES = {
    "int_type": "expected an integer",
    "float_type": "expected a number",
    "bool_type": "expected true or false",
    "string_type": "expected a text",
    "finite_number": "expected a finite number",
    "literal_error": "expected one of {expected}",
    "greater_than": "must be > {gt}",
    "greater_than_equal": "must be >= {ge}",
    "less_than": "must be < {lt}",
    "less_than_equal": "must be <= {le}",
    "multiple_of": "must be a multiple of {multiple_of}",
    "tuple_type": "expected a list",
    "list_type": "expected a list",
    "dict_type": "expected a mapping",
    "too_short": "expected at least {min_length} item(s)",
    "too_long": "expected at most {max_length} item(s)",
}


def _leaf(hint: Any, value: Any, key: str, where: str) -> Any:
    """``value`` checked (and, for ints into floats and lists into tuples, converted) for the
    field type ``hint``; ConfigError naming ``key`` otherwise."""
    from pydantic import ValidationError  # on first use (see _strict_config)

    if isinstance(value, list) and get_origin(_bare(hint)) is tuple:
        value = tuple(value)
    try:
        return _adapter(hint).validate_python(value)
    except ValidationError as exc:
        err = exc.errors()[0]
        phrase = _PHRASES.get(err["type"])
        text = phrase.format(**err.get("ctx", {})) if phrase else err["msg"]
        sub = "".join(f"[{p}]" if isinstance(p, int) else "" for p in err.get("loc", ()))
        raise ConfigError(f"{_prefix(where)}{key}{sub}: {text}, got {_show(value)}") from None


_OPS: dict[str, tuple[str, Any]] = {
    "gt": (">", lambda v, b: v > b), "ge": (">=", lambda v, b: v >= b),
    "lt": ("<", lambda v, b: v < b), "le": ("<=", lambda v, b: v <= b)}


def _bounds(hint: Any) -> list[tuple[str, Any]]:
    """The ``(name, limit)`` bounds (``"gt"``, ``"ge"``, ``"lt"``, ``"le"``) an ``Annotated``
    hint declares (``annotated_types`` Gt/Ge/Lt/Le/Interval or a pydantic ``Field``)."""
    import annotated_types                # on first use (see _strict_config)

    out: list[tuple[str, Any]] = []
    while get_origin(hint) is typing.Annotated:
        hint, *meta = get_args(hint)
        stack = list(meta)
        while stack:
            m = stack.pop(0)
            inner = getattr(m, "metadata", None)      # a pydantic FieldInfo
            if isinstance(inner, list):
                stack[:0] = inner
                continue
            if isinstance(m, annotated_types.GroupedMetadata):     # Interval
                stack[:0] = list(m)
                continue
            out += [(n, getattr(m, n)) for n in _OPS if getattr(m, n, None) is not None]
    return out


def check_bounds(obj: Any, *, where: str = "", path: str = "") -> None:
    """Check the ``Annotated`` bounds of every number field of dataclass ``obj`` and of its
    nested dataclass fields; :class:`ConfigError` ``"key: must be > 0, got -1"`` (the dotted
    key from ``path``) on the first value outside them. The loader checks the same bounds
    (and the types) of values from files and ``--set``; this is for objects built in code."""
    hints = _hints(type(obj))
    for f in _init_fields(type(obj)):
        value, key = getattr(obj, f.name), _join(path, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            check_bounds(value, where=where, path=key)
            continue
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            continue
        for name, limit in _bounds(hints[f.name]):
            sign, ok = _OPS[name]
            if _bare(hints[f.name]) is float:        # shown as the loader's check shows it
                limit = float(limit)
            if not ok(value, limit):
                raise ConfigError(f"{_prefix(where)}{key}: must be {sign} {limit}, got "
                                  f"{_show(value)}")


def _construct(cls: type[T], kwargs: dict[str, Any], path: str, where: str) -> T:
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{_prefix(where)}{exc}") from None
    except (ValueError, UserError) as exc:
        raise ConfigError(f"{_prefix(where)}{exc}") from None


def _build(cls: type[T], tree: Any, base: T | None, path: str, where: str,
           renamed: Mapping[str, str]) -> T:
    if not isinstance(tree, Mapping):
        raise ConfigError(f"{_prefix(where)}{path or 'the top level'}: expected a mapping of "
                          f"keys to values, got {_show(tree)}")
    names = {f.name for f in _init_fields(cls)}
    for name in tree:
        if not isinstance(name, str):
            at = f"{path}: " if path else ""
            raise ConfigError(f"{_prefix(where)}{at}not a mapping of config keys (found the key "
                              f"{_show(name)}, not a name); write 'key: value' lines, e.g. "
                              f"'{sorted(names)[0]}: ...'")
        if name not in names:
            raise _unknown(cls, path, name, where, renamed)
    hints = _hints(cls)
    kwargs: dict[str, Any] = {}
    for f in _init_fields(cls):
        key = _join(path, f.name)
        hint = hints[f.name]
        if f.name in tree:
            value = tree[f.name]
            if _is_config_class(hint) and not isinstance(value, hint):
                sub = getattr(base, f.name) if base is not None else None
                kwargs[f.name] = _build(hint, value, sub, key, where, renamed)
            elif _is_config_class(hint):
                kwargs[f.name] = value
            else:
                kwargs[f.name] = _leaf(hint, value, key, where)
        elif base is not None:
            kwargs[f.name] = getattr(base, f.name)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{_prefix(where)}missing config key {key}")
    return _construct(cls, kwargs, path, where)


def from_tree(cls: type[T], tree: Any, *, base: T | None = None, where: str = "",
              renamed: Mapping[str, str] = {}) -> T:
    """Build a ``cls`` (a dataclass) from a mapping (e.g. :func:`read_yaml`'s result).

    Keys not in ``tree`` take ``base``'s values (``base`` None: the dataclass defaults; a field
    without a default must then be given). ``renamed`` maps old dotted keys to advice shown
    instead of "unknown config key" (e.g. ``{"astro.tau_ca": "give astro.tau_ca_s"}``).
    Raises :class:`ConfigError` (one line, prefixed with ``where``).
    """
    if tree is None:
        tree = {}
    return _build(cls, tree, base, "", where, renamed)


def _nest(cls: type, overrides: Mapping[str, Any], where: str,
          renamed: Mapping[str, str]) -> dict[str, Any]:
    """``{"a.b": 1, "a.c": 2}`` -> ``{"a": {"b": 1, "c": 2}}`` after checking every key."""
    tree: dict[str, Any] = {}
    for dotted, value in overrides.items():
        parts, _hint = _resolve(cls, dotted, where, renamed)
        node = tree
        for part in parts[:-1]:
            nxt = node.get(part)
            if not isinstance(nxt, dict):
                nxt = node[part] = {} if not isinstance(nxt, Mapping) else dict(nxt)
            node = nxt
        last = parts[-1]
        if isinstance(value, Mapping) and isinstance(node.get(last), Mapping):
            node[last] = {**node[last], **value}
        else:
            node[last] = value
    return tree


def apply(obj: T, overrides: Mapping[str, Any], *, where: str = "",
          renamed: Mapping[str, str] = {}) -> T:
    """A copy of dataclass ``obj`` with dotted keys set to typed values.

    ``apply(cfg, {"astro.a": 6.0, "grid": {"rows": 4}})``; a mapping on a section key sets the
    keys it names and keeps the others; a dataclass instance replaces the section. Each value
    is checked for its field's type; the changed dataclasses are rebuilt (their
    ``__post_init__`` checks run). Raises :class:`ConfigError`.
    """
    if not overrides:
        return obj
    return _build(type(obj), _nest(type(obj), overrides, where, renamed), obj, "", where,
                  renamed)


def check_keys(cls: type, overrides: Mapping[str, Any], *, where: str = "",
               renamed: Mapping[str, str] = {}) -> dict[str, Any]:
    """``overrides`` (dotted keys to typed values) with every key checked against dataclass
    ``cls`` and every leaf value checked (and converted: ints to floats, lists to tuples) for
    its field's type, without building a ``cls``; section values (mappings) are kept for
    :func:`apply`. Raises :class:`ConfigError`."""
    out: dict[str, Any] = {}
    for dotted, value in overrides.items():
        parts, hint = _resolve(cls, dotted, where, renamed)
        key = ".".join(parts)
        out[key] = value if _is_config_class(hint) else _leaf(hint, value, key, where)
    return out


def parse_assignments(cls: type, items: Iterable[str], *, option: str = "--set",
                      renamed: Mapping[str, str] = {}) -> dict[str, Any]:
    """``["section.key=TEXT", ...]`` -> ``{"section.key": typed value}`` for dataclass ``cls``.

    TEXT is read for the field's type (module doc); later items win. Raises
    :class:`ConfigError` naming the item (``"--set grid.rows=x: grid.rows: expected ..."``).
    """
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = str(item).partition("=")
        where = f"{option} {item}"
        if not sep or not key.strip():
            raise ConfigError(f"{where}: expected KEY=VALUE, e.g. {option} astro.a=6")
        _parts, hint = _resolve(cls, key, where, renamed)
        if _takes_text(hint):
            value: Any = text.strip()
        else:
            value = parse_yaml(text, where) if text.strip() else None
        out.update(check_keys(cls, {key: value}, where=where, renamed=renamed))
    return out


def load(cls: type[T], path: str | os.PathLike | Any, *, base: T | None = None,
         overrides: Mapping[str, Any] = {}, sets: Iterable[str] = (), what: str = "config file",
         renamed: Mapping[str, str] = {}) -> T:
    """Read a YAML 1.2 file into a ``cls``, then apply typed ``overrides`` and ``--set`` texts.

    ``base`` supplies the values the file does not give (None: the dataclass defaults).
    Raises :class:`ConfigError`.
    """
    tree = read_yaml(path, what=what)
    obj = from_tree(cls, tree, base=base, where=f"{what} {path}", renamed=renamed)
    obj = apply(obj, overrides, renamed=renamed)
    return apply(obj, parse_assignments(cls, sets, renamed=renamed), renamed=renamed)


def to_tree(obj: Any) -> dict[str, Any]:
    """A dataclass tree as plain nested dicts (``dataclasses.asdict``)."""
    return dataclasses.asdict(obj)


def differences(a: Mapping[str, Any], b: Mapping[str, Any], *, prefix: str = ""
                ) -> list[tuple[str, Any, Any]]:
    """``(dotted key, a's value, b's value)`` wherever two plain trees differ, in ``a``'s key
    order, then ``b``'s extra keys; a key only one side has gives :data:`MISSING` on the other.
    Numbers compare by value (``6 == 6.0``)."""
    out: list[tuple[str, Any, Any]] = []
    keys = list(a) + [k for k in b if k not in a]
    for k in keys:
        key = _join(prefix, str(k))
        va, vb = a.get(k, MISSING), b.get(k, MISSING)
        if isinstance(va, Mapping) and isinstance(vb, Mapping):
            out += differences(va, vb, prefix=key)
        elif isinstance(va, (list, tuple)) and isinstance(vb, (list, tuple)):
            if list(va) != list(vb):
                out.append((key, va, vb))
        elif va != vb or isinstance(va, bool) != isinstance(vb, bool):
            out.append((key, va, vb))
    return out
