"""Config nodes checked before they are built, and the resolvers the configs use.

Field types are checked against the ``_target_``'s annotations, ``_target_`` values of configs
that came with someone else's files against an allow-list, and the constructors' range checks
become :class:`InputError`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import enum
import importlib
import inspect
import types
import typing
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from .errors import InputError
from .paths import check_name

__all__ = [
    "check_node",
    "check_targets",
    "config_errors",
    "register_config_resolvers",
    "switches_from_dict",
]


@contextlib.contextmanager
def config_errors() -> Iterator[None]:
    """Turn the ValueErrors of objects built from the config into :class:`InputError`.

    The config's dataclasses and modules validate their fields in their constructors with a
    ValueError that names the field; while they are built from a command line, that is the
    user's error. Hydra's ``instantiate`` wraps it, so the wrapper is unwrapped first.
    """
    try:
        yield
    except Exception as exc:
        cause: BaseException | None = exc
        while cause is not None and type(cause).__module__.startswith("hydra."):
            cause = cause.__cause__
        if isinstance(cause, InputError) or not isinstance(cause, ValueError):
            raise
        raise InputError(" ".join(str(cause).split())) from exc


def register_config_resolvers() -> None:
    """OmegaConf resolvers the configs use: ``${path_component:<field>,<value>}``.

    A run folder's path is resolved by Hydra before the command runs; a name in it that is
    not a single path component (``run_name=../../x``) is refused there, before any folder
    is made.
    """
    from omegaconf import OmegaConf

    if not OmegaConf.has_resolver("path_component"):
        OmegaConf.register_new_resolver(
            "path_component", lambda field, value: check_name(value, str(field))
        )


def check_node(values: Any, field: str) -> None:
    """Type-check an instantiable config node against its ``_target_``'s annotations.

    Each key must be a parameter of the target (a dataclass field, a function argument) and
    its value must fit the annotation: ``sim.max_dt=abc`` is refused as ``sim.max_dt must be
    a number, got 'abc'`` before the target is built. Nested nodes (a value with its own
    ``_target_``, or a mapping for a dataclass-typed field) are checked too. Annotations that
    a config value cannot be judged against (modules, callables) are left to the target.
    Range checks stay with the target's own validation (see :func:`config_errors`).

    Args:
        values: The node as a plain mapping or a resolved ``DictConfig``.
        field: Its dotted name on the command line (``sim``, ``render.camera``).
    """
    target = values.get("_target_") if isinstance(values, Mapping) else None
    if target is None:
        return
    try:
        obj = _import_target(str(target))
    except (ImportError, AttributeError) as err:
        raise InputError(f"{field}._target_: cannot import {target!r} ({err})") from None
    _check_params(values, _params_of(obj), field)


def check_targets(node: Any, field: str, allowed: Iterable[str]) -> None:
    """Refuse a config whose ``_target_`` entries, nested ones included, are not all allowed.

    A config that came with someone else's files (a checkpoint's ``net_config``, a run
    folder's ``.hydra/config.yaml``) is data: instantiating an arbitrary ``_target_`` would
    call any importable function. Every node is checked before anything is imported.

    Args:
        node: A plain mapping or list (``OmegaConf.to_container`` of a config).
        field: Where the node came from, for the message (``net_config``, ``run config``).
        allowed: Dotted names that may be instantiated.
    """
    names = set(allowed)

    def walk(value: Any, key: str) -> None:
        if isinstance(value, Mapping):
            for name, item in value.items():
                name = str(name)
                where = f"{key}.{name}" if key else name
                if name == "_target_" and (not isinstance(item, str) or item not in names):
                    raise InputError(
                        f"{field}: {where} is {item!r}, which is not one of the allowed "
                        f"targets: {', '.join(sorted(names))}"
                    )
                walk(item, where)
        elif isinstance(value, list | tuple):
            for index, item in enumerate(value):
                walk(item, f"{key}[{index}]")

    walk(node, "")


def _import_target(path: str) -> Any:
    parts = path.split(".")
    for cut in range(len(parts) - 1, 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for name in parts[cut:]:
            obj = getattr(obj, name)
        return obj
    return importlib.import_module(path)


def _params_of(obj: Any) -> dict[str, Any] | None:
    """Parameter name -> annotation (``Any`` where none); ``None`` if it takes ``**kwargs``."""
    if dataclasses.is_dataclass(obj) and isinstance(obj, type):
        try:
            hints = typing.get_type_hints(obj)
        except Exception:  # an annotation that does not resolve: check names only
            hints = {}
        return {f.name: hints.get(f.name, Any) for f in dataclasses.fields(obj) if f.init}
    function = typing.cast(Any, obj).__init__ if isinstance(obj, type) else obj
    try:
        signature = inspect.signature(function)
    except (TypeError, ValueError):
        return None
    try:
        hints = typing.get_type_hints(function)
    except Exception:
        hints = {}
    params = {}
    for name, param in signature.parameters.items():
        if param.kind is param.VAR_KEYWORD:
            return None
        if param.kind is not param.VAR_POSITIONAL and name != "self":
            params[name] = hints.get(name, Any)
    return params


def _check_params(values: Mapping, params: dict[str, Any] | None, field: str) -> None:
    for key, value in values.items():
        key = str(key)
        if key.startswith("_"):
            continue
        name = f"{field}.{key}"
        if params is not None and key not in params:
            raise InputError(f"{name} is not a field of {field}; allowed: {', '.join(params)}")
        if isinstance(value, Mapping) and "_target_" in value:
            check_node(value, name)
            continue
        annotation = Any if params is None else params[key]
        if value == "???":
            continue  # a required value Hydra reports itself
        if _fits(value, annotation) is False:
            raise InputError(f"{name} must be {_describe(annotation)}, got {value!r}")
        data_class = _dataclass_in(annotation)
        if data_class is not None and isinstance(value, Mapping):
            _check_params(value, _params_of(data_class), name)


_SCALARS = (str, int, float, bool, type(None))


def _is_union(annotation: Any) -> bool:
    return typing.get_origin(annotation) in (typing.Union, types.UnionType)


def _dataclass_in(annotation: Any) -> type | None:
    members = typing.get_args(annotation) if _is_union(annotation) else (annotation,)
    found = [m for m in members if isinstance(m, type) and dataclasses.is_dataclass(m)]
    return found[0] if len(found) == 1 else None


def _fits(value: Any, annotation: Any) -> bool | None:
    """Whether a config value fits ``annotation``: True, False, or None (cannot tell)."""
    if annotation is Any or isinstance(annotation, typing.TypeVar | str):
        return None
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if _is_union(annotation):
        results = [_fits(value, member) for member in args]
        if True in results:
            return True
        return False if all(r is False for r in results) else None
    if origin is typing.Literal:
        return any(value == a and type(value) is type(a) for a in args)
    if annotation is type(None):
        return value is None
    if annotation is bool:
        return isinstance(value, bool)
    if annotation is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if annotation is float:
        return isinstance(value, int | float) and not isinstance(value, bool)
    if annotation is str:
        return isinstance(value, str)
    if annotation is Path or (isinstance(annotation, type) and issubclass(annotation, Path)):
        return isinstance(value, str | Path)
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        return any(value == m.value or value == m.name for m in annotation)
    if origin in (tuple, list, Sequence) or annotation in (tuple, list):
        if not isinstance(value, list | tuple):
            return False if isinstance(value, _SCALARS) else None
        if not args:
            return True
        if origin is tuple and not (len(args) == 2 and args[1] is Ellipsis):
            if len(value) != len(args):
                return False
            results = [_fits(v, a) for v, a in zip(value, args, strict=True)]
        else:
            results = [_fits(v, args[0]) for v in value]
        return False if False in results else (None if None in results else True)
    if isinstance(annotation, type) and dataclasses.is_dataclass(annotation):
        return isinstance(value, Mapping | annotation) or (
            False if isinstance(value, _SCALARS) else None
        )
    if isinstance(annotation, type) and _config_cannot_be(annotation):
        return False if isinstance(value, _SCALARS) else None
    return None


def _config_cannot_be(cls: type) -> bool:
    """Classes a plain config value never is (tensors, modules), though a target may say so."""
    names = {f"{c.__module__}.{c.__qualname__}" for c in cls.__mro__}
    return bool(names & {"torch.Tensor", "torch.nn.modules.module.Module"})


_PLURAL: dict[Any, str] = {
    int: "integers",
    float: "numbers",
    bool: "booleans",
    str: "strings",
    Path: "paths",
}


def _describe(annotation: Any) -> str:
    """What a value of ``annotation`` is, in words (for the error message)."""
    members = typing.get_args(annotation) if _is_union(annotation) else (annotation,)
    literals: list[Any] = []
    words: list[str] = []
    for member in members:
        if typing.get_origin(member) is typing.Literal:
            literals += list(typing.get_args(member))
        elif isinstance(member, type) and issubclass(member, enum.Enum):
            literals += [m.value for m in member]
        elif (word := _noun(member)) and word not in words:
            words.append(word)
    if literals:
        words.insert(0, "one of " + ", ".join(dict.fromkeys(map(str, literals))))
    return " or ".join(words) or "a valid value"


def _noun(annotation: Any) -> str:
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    simple = {
        int: "an integer",
        float: "a number",
        bool: "true or false",
        str: "text",
        type(None): "null",
        Path: "a path",
    }
    if annotation in simple:
        return simple[annotation]
    if origin in (tuple, list, Sequence):
        if origin is tuple and args and not (len(args) == 2 and args[1] is Ellipsis):
            item = args[0] if len(set(args)) == 1 else None
            return f"a list of {len(args)} {_PLURAL.get(item, 'values')}"
        item = args[0] if args else None
        if _is_union(item):
            item = next((a for a in typing.get_args(item) if a in _PLURAL), None)
        return f"a list of {_PLURAL.get(item, 'values')}"
    if isinstance(annotation, type) and dataclasses.is_dataclass(annotation):
        return f"a mapping of {annotation.__name__} fields"
    return ""


def switches_from_dict(cls, values, label: str):
    """Instantiate the switch dataclass ``cls`` from a mapping, rejecting unknown keys.

    Shared by the physical switches (:mod:`simulator.cloth.effects`) and the visual ones
    (:mod:`render.effects`).

    The error names the unknown keys and the allowed ones, prefixed by ``label``.
    """
    values = dict(values or {})
    allowed = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - allowed)
    if unknown:
        raise ValueError(f"{label}: unknown {unknown}; allowed: {sorted(allowed)}")
    return cls(**values)
