"""Type hints checked against values as a config file or the command line gives them, and named in words.

type_matches(3, float)                # True: a file's integer is a fine float
type_words(int | None)                 # 'an integer (or none)'
"""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from typing import Any, TypeVar


def parse_value(raw: str) -> Any:
    """A command-line value: JSON where it parses, none / null / true / false in any case, else the string."""
    try:
        return json.loads(raw)
    except json.JSONDecodeError:
        return {"none": None, "null": None, "true": True, "false": False}.get(raw.lower(), raw)


def type_matches(value: Any, hint: Any) -> bool:
    """Whether `value` (as JSON, TOML or a key=value override gives it) fits the type hint `hint`.

    int accepts no bool or float; float accepts int; a list or tuple fits list[...] and tuple[...] hints
    (files give lists), element by element.
    """
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is Any or isinstance(hint, TypeVar):
        return True
    if origin in (typing.Union, types.UnionType):
        return any(type_matches(value, a) for a in args)
    if hint is type(None) or hint is None:
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint is str:
        return isinstance(value, str)
    if origin in (list, tuple) or hint in (list, tuple):
        if not isinstance(value, (list, tuple)):
            return False
        if origin is tuple and args and args[-1] is not Ellipsis:
            return len(value) == len(args) and all(map(type_matches, value, args))
        return not args or all(type_matches(v, args[0]) for v in value)
    if origin is dict or hint is dict:
        return isinstance(value, dict)
    if dataclasses.is_dataclass(hint):
        return isinstance(value, hint)
    return True


def type_words(hint: Any) -> str:
    """A type hint in words for error messages: 'a number', 'a list of numbers', 'a pair', ..."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        words = [type_words(a) for a in args if a is not type(None)]
        return " or ".join(words) + (" (or none)" if type(None) in args else "")
    simple = {bool: "true or false", int: "an integer", float: "a number", str: "a string", dict: "a table"}
    if hint in simple:
        return simple[hint]
    if origin is dict:
        return "a table"
    if origin in (list, tuple):
        if origin is tuple and args and args[-1] is not Ellipsis:
            return f"a list of {len(args)} values ({', '.join(type_words(a) for a in args)})"
        return "a list" + (f" of {type_words(args[0])} values" if args else "")
    if dataclasses.is_dataclass(hint):
        return f"a table of {hint.__name__} fields"
    return getattr(hint, "__name__", str(hint))


def dataclass_type(hint: Any) -> type | None:
    """The dataclass a hint names (itself, or one of a union's members, e.g. DataConfig | None), else None."""
    for candidate in (hint, *typing.get_args(hint)):
        if dataclasses.is_dataclass(candidate):
            return candidate
    return None
