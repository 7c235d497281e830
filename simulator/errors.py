"""Errors a user can fix, field checks that raise them, and the one-line report at entry points.

An entry point (a ``@hydra.main`` function) is wrapped with :func:`report_user_errors`: an
:class:`InputError` (or another error a user can fix: ``FileNotFoundError`` and the packages'
domain errors, see ``_user_errors``) prints one line ``error: <message>`` on stderr and exits
with status 2, instead of a traceback. Programming errors still raise with their traceback.
Messages name the field and the allowed values.

An entry point checks every field before it does any work: scalars with :func:`check_int`,
:func:`check_float`, :func:`check_choice`, :func:`check_bool` and :func:`check_device` (class ids:
:func:`simulator.cloth.material.check_class_ids`); instantiable nodes with :func:`check_node` (types
from the target's annotations); and it builds them inside :func:`config_errors`, so that the range
checks of their constructors (a ValueError naming the field) become :class:`InputError` too.
"""

from __future__ import annotations

import contextlib
import dataclasses
import enum
import errno
import functools
import importlib
import inspect
import math
import os
import shutil
import sys
import types
import typing
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any


class InputError(ValueError):
    """Bad user input; the message names the field and the allowed values."""


class MaterialError(ValueError):
    """An unknown material or class, a malformed material file, or a modulus out of range."""


_DOMAIN_ERRORS: list[type[BaseException]] = [MaterialError]
"""Domain errors of the packages above the core that a user can fix (see :func:`user_error`)."""


def user_error(cls: type[BaseException]) -> type[BaseException]:
    """Class decorator: ``cls`` is an error a user can fix, reported in one line at entry points.

    Packages above the core register their domain errors this way (the core never imports
    them).
    """
    if cls not in _DOMAIN_ERRORS:
        _DOMAIN_ERRORS.append(cls)
    return cls


def _user_errors() -> tuple[type[BaseException], ...]:
    """Errors a user can fix: ours, plus the registered domain errors of the packages."""
    from simulator.mesh import MeshError

    return (InputError, FileNotFoundError, MeshError, *_DOMAIN_ERRORS)


INTERRUPTED = "interrupted; rerun the same command to resume"
"""The line Ctrl-C ends a command with (exit status 130, as a shell reports SIGINT)."""

_ENVIRONMENT_ERRNOS = frozenset({
    errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOTDIR, errno.EISDIR,
    errno.EDQUOT, errno.ENAMETOOLONG, errno.EFBIG, errno.EEXIST,
})  # fmt: skip
"""File-system errors a user fixes (a full disk, a read-only or wrong destination)."""


def _chain(exc: BaseException) -> Iterator[BaseException]:
    """``exc`` and the errors it was raised from or during (``__cause__``, ``__context__``)."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen and len(seen) < 16:
        seen.add(id(current))
        yield current
        current = current.__cause__ or current.__context__


def _wrapper_module(exc: BaseException) -> bool:
    """Errors of the config machinery that wrap the error raised inside it."""
    return type(exc).__module__.split(".")[0] in ("hydra", "omegaconf")


def _user_error_in(exc: BaseException) -> BaseException | None:
    """The error a user can fix that ``exc`` is or wraps, else ``None``.

    Hydra's ``instantiate`` and OmegaConf's interpolation resolvers wrap the error raised
    inside them; a file-system error (a full disk, a read-only destination) is the user's too.
    """
    user = _user_errors()
    for current in _chain(exc):
        if isinstance(current, user):
            return current
        if isinstance(current, OSError) and current.errno in _ENVIRONMENT_ERRNOS:
            return current
        if not _wrapper_module(current):
            return None
    return None


_CONFIG_ERRORS = frozenset({
    "hydra.errors.ConfigCompositionException", "hydra.errors.MissingConfigException",
    "hydra.errors.OverrideParseException", "omegaconf.errors.MissingMandatoryValue",
})  # fmt: skip
"""Hydra's own refusals of a command line: an override that does not parse or fit."""


def _config_error(exc: BaseException) -> bool:
    return any(f"{c.__module__}.{c.__name__}" in _CONFIG_ERRORS for c in type(exc).__mro__)


def _message(exc: BaseException) -> str:
    key = getattr(exc, "full_key", None)
    if type(exc).__name__ == "MissingMandatoryValue" and key:
        return f"{key} is required: give {key}=<value> on the command line"
    if isinstance(exc, OSError) and exc.strerror and exc.filename is not None:
        if exc.errno == errno.EEXIST:
            return f"cannot make the folder {exc.filename}: a file of that name exists"
        return f"cannot write {exc.filename}: {exc.strerror}"
    return " ".join(str(exc).split())  # one line, whatever the message held


def register_config_resolvers() -> None:
    """OmegaConf resolvers the configs use: ``${path_component:<field>,<value>}``.

    A run folder's path is resolved by Hydra before the command runs; a name in it that is
    not a single path component (``run_name=../../x``) is refused there, before any folder
    is made.
    """
    omegaconf = sys.modules.get("omegaconf")  # loaded by every command that has configs
    if omegaconf is not None and not omegaconf.OmegaConf.has_resolver("path_component"):
        omegaconf.OmegaConf.register_new_resolver(
            "path_component", lambda field, value: check_name(value, str(field))
        )


def report_user_errors(main: Callable[..., Any]) -> Callable[..., Any]:
    """Wrap a command so that a user error prints one line and exits with status 2.

    Ctrl-C prints :data:`INTERRUPTED` and exits with 130, whether it arrived in Python or in
    compiled code (numba reports it as a ``SystemError`` raised during the interrupt).
    Programming errors keep their traceback. Put it outside ``@hydra.main`` as well as on
    the task: outside, it also reports what Hydra raises while composing the config and
    making the run folder (it sets ``HYDRA_FULL_ERROR`` so that Hydra passes errors on).
    """

    @functools.wraps(main)
    def wrapped(*args, **kwargs):
        os.environ["HYDRA_FULL_ERROR"] = "1"
        register_config_resolvers()
        stderr = sys.stderr
        if not isinstance(stderr, _LineEnds):
            sys.stderr = _LineEnds(stderr)
        try:
            return main(*args, **kwargs)
        except (Exception, KeyboardInterrupt) as exc:
            _close_progress_bars()
            if any(isinstance(e, KeyboardInterrupt) for e in _chain(exc)):
                _last_line(INTERRUPTED)
                raise SystemExit(130) from None
            user = _user_error_in(exc)
            if user is None and _config_error(exc):
                user = exc
            if user is None:
                raise
            _last_line(f"error: {_message(user)}")
            raise SystemExit(2) from None
        finally:
            sys.stderr = stderr

    return wrapped


class _LineEnds:
    """``sys.stderr`` that remembers whether its last write ended a line (a bar's does not)."""

    def __init__(self, stream):
        self._stream = stream
        self.at_line_start = True

    def write(self, text: str) -> int:
        """Write ``text`` to the stream."""
        if text:
            self.at_line_start = text.endswith("\n")
        return self._stream.write(text)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def _last_line(text: str) -> None:
    """Print a command's last line on stderr, on a line of its own."""
    if not getattr(sys.stderr, "at_line_start", True):
        print(file=sys.stderr)
    print(text, file=sys.stderr)


def _close_progress_bars() -> None:
    """Close the tqdm bars still open, so that they do not redraw over the last line."""
    tqdm = sys.modules.get("tqdm")
    if tqdm is None:
        return
    for bar in list(getattr(tqdm.tqdm, "_instances", ())):
        with contextlib.suppress(Exception):  # a bar interrupted while it was being set up
            bar.close()


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


def check_int(value: Any, field: str, low: int | None = None, high: int | None = None) -> int:
    """``value`` as an int in ``[low, high]``; refuses bools, non-integral floats and text."""
    ok = isinstance(value, int) and not isinstance(value, bool)
    if isinstance(value, float) and value.is_integer():
        value, ok = int(value), True
    if isinstance(value, str):
        try:
            value, ok = int(value.strip()), True
        except ValueError:
            ok = False
    if not ok:
        raise InputError(f"{field} must be an integer{_range_text(low, high)}, got {value!r}")
    if (low is not None and value < low) or (high is not None and value > high):
        raise InputError(f"{field} must be an integer{_range_text(low, high)}, got {value}")
    return int(value)


def check_float(
    value: Any,
    field: str,
    low: float | None = None,
    high: float | None = None,
    *,
    low_open: bool = False,
) -> float:
    """``value`` as a finite float in ``[low, high]`` (``(low, high]`` with ``low_open``)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if isinstance(value, bool) or not math.isfinite(number):
        raise InputError(
            f"{field} must be a finite number{_range_text(low, high, low_open)}, got {value!r}"
        )
    below = low is not None and (number <= low if low_open else number < low)
    if below or (high is not None and number > high):
        raise InputError(
            f"{field} must be a number{_range_text(low, high, low_open)}, got {number:g}"
        )
    return number


def check_choice(value: Any, field: str, choices: Iterable[Any]) -> Any:
    """``value`` if it is one of ``choices``."""
    allowed = list(choices)
    if value not in allowed:
        raise InputError(f"{field} must be one of {', '.join(map(str, allowed))}; got {value!r}")
    return value


def check_bool(value: Any, field: str) -> bool:
    """``value`` if it is a bool (``true`` / ``false`` on the command line)."""
    if not isinstance(value, bool):
        raise InputError(f"{field} must be true or false, got {value!r}")
    return value



def check_name(value: Any, field: str) -> str:
    """``value`` as a single path component: a file or folder name, never a path.

    Names become parts of paths (run folders, report folders); one with a separator, ``..``
    or a NUL could point outside the folder it is meant for.
    """
    text = str(value) if isinstance(value, int) and not isinstance(value, bool) else value
    if (
        not isinstance(text, str)
        or not text.strip()
        or text != text.strip()
        or text in (".", "..")
        or any(c in text for c in ("/", "\\", "\x00"))
    ):
        raise InputError(
            f"{field} must be a single file or folder name (no '/' or '\\', not '.' or "
            f"'..'), got {value!r}"
        )
    return text


def resolve_inside(root: str | Path, name: str, field: str) -> Path:
    """``root / name`` resolved, refused unless it stays inside ``root`` (links followed)."""
    base = Path(root).resolve()
    path = (base / name).resolve()
    if not path.is_relative_to(base):
        raise InputError(f"{field} {name!r} points outside {root} (to {path}); keep files in it")
    return path


MIN_FREE_BYTES = 64 * 2**20
"""Free space an output folder must have before a command starts [bytes]."""


def _existing_ancestor(path: Path) -> Path:
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_output_dir(value: Any, field: str, *, min_free_bytes: int = MIN_FREE_BYTES) -> Path:
    """``value`` as a folder that outputs can be written into, checked before any work.

    Refused in one line: a path that is a file (or lies below one), a folder this process
    may not write (permissions, a read-only file system) and a disk with less than
    ``min_free_bytes`` free. Nothing is created.
    """
    if not isinstance(value, str | Path) or not str(value).strip():
        raise InputError(f"{field} must be a folder path, got {value!r}")
    path = Path(value)
    if path.exists() and not path.is_dir():
        raise InputError(f"{field}: {path} exists and is not a folder")
    base = _existing_ancestor(path.absolute())
    if not base.is_dir():
        raise InputError(f"{field}: {base} is a file, so {path} cannot be made below it")
    if not os.access(base, os.W_OK | os.X_OK):
        why = "a read-only file system" if _read_only(base) else "no write permission"
        raise InputError(f"{field}: {path} cannot be written ({base}: {why})")
    free = shutil.disk_usage(base).free
    if free < min_free_bytes:
        raise InputError(
            f"{field}: {path} is on a disk with {free / 2**20:.1f} MiB free; at least "
            f"{min_free_bytes / 2**20:.0f} MiB are needed"
        )
    return path


def check_output_file(value: Any, field: str, *, min_free_bytes: int = MIN_FREE_BYTES) -> Path:
    """``value`` as a file path whose folder can take it (:func:`check_output_dir`)."""
    if not isinstance(value, str | Path) or not str(value).strip():
        raise InputError(f"{field} must be a file path, got {value!r}")
    path = Path(value)
    if path.is_dir():
        raise InputError(f"{field}: {path} is a folder; give a file path")
    check_output_dir(path.parent, field, min_free_bytes=min_free_bytes)
    return path


def _read_only(path: Path) -> bool:
    try:
        return bool(os.statvfs(path).f_flag & os.ST_RDONLY)
    except OSError:
        return False


def check_device(value: Any, field: str) -> str:
    """A torch device name (``auto``, ``cpu``, ``cuda``, ``cuda:N``) this machine has."""
    import torch

    text = str(value).strip().lower()
    if text not in ("auto", "cpu", "cuda") and not (
        text.startswith("cuda:") and text[5:].isdigit()
    ):
        raise InputError(f"{field} must be one of auto, cpu, cuda, cuda:N; got {value!r}")
    if text.startswith("cuda"):
        require_cuda(f"{field}={value}", f"use {field}=cpu or {field}=auto")
        index = int(text[5:]) if ":" in text else 0
        if index >= torch.cuda.device_count():
            raise InputError(
                f"{field}={value}: this machine has {torch.cuda.device_count()} CUDA device(s)"
            )
    return text


def require_cuda(request: str, alternative: str) -> None:
    """Refuse ``request`` (e.g. ``trainer.accelerator=gpu``) in one line when there is no CUDA."""
    import torch

    if not torch.cuda.is_available():
        raise InputError(
            f"{request} asks for CUDA, but this machine has no CUDA device "
            f"(torch.cuda.is_available() is false); {alternative}"
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
                if name == "_target_" and (
                    not isinstance(item, str) or item not in names
                ):
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
        int: "an integer", float: "a number", bool: "true or false", str: "text",
        type(None): "null", Path: "a path",
    }  # fmt: skip
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


def _range_text(low, high, low_open: bool = False) -> str:
    if low is not None and high is not None:
        return f" in {'(' if low_open else '['}{low}, {high}]"
    if low is not None:
        return f" {'>' if low_open else '>='} {low}"
    if high is not None:
        return f" <= {high}"
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
