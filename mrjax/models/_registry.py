"""Model registry: `mrjax.models.get(name)`, `register`, and where each model came from.

Models come from five places, listed by :func:`names` in this order:

1. mrjax's hand-written models of the paper (`bingham`, `kwok`, `bouc_wen`,
    `modified_bouc_wen`, `dahl`);
2. mrjax's literature models, declared through the public contract (`mrjax.models.Model`);
3. models registered in this process (:func:`register`);
4. installed packages, through the entry-point group `mrjax.models` (`name = "pkg.mod:obj"`);
5. a file or module named where a model is asked for: `"path/to/file.py:Name"` or
    `"package.module:Name"` (the command line's `--model`).

:func:`source_of` says where a model came from, and which of its parameters are held
(`mrjax.models.fix`); fit.json records it and :func:`from_source` finds the model again in
another process (`mrjax predict --fit DIR`).
"""

from __future__ import annotations

import difflib
import hashlib
import importlib
import importlib.util
import sys
import warnings
import weakref
from collections.abc import Mapping
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Any

from .._errors import InputError
from ._base import AbstractModel
from ._declare import Model
from ._fixed import fix
from ._hysteretic import BoucWen, Dahl, ModifiedBoucWen
from ._literature import LITERATURE
from ._names import ALIASES, BUILTIN_NAMES, LITERATURE_NAMES, reserved_names
from ._static import Bingham, Kwok

#: The entry-point group through which an installed package adds models.
ENTRY_POINT_GROUP = "mrjax.models"

_BUILTIN: dict[str, type[AbstractModel]] = {
    cls.name: cls for cls in (Bingham, Kwok, BoucWen, ModifiedBoucWen, Dahl)
}
assert tuple(_BUILTIN) == BUILTIN_NAMES and tuple(LITERATURE) == LITERATURE_NAMES
_ALIASES = ALIASES
_LITERATURE_CACHE: dict[str, AbstractModel] = {}
_USER: dict[str, AbstractModel] = {}
#: where each non-built-in model came from, and the values the object there holds fixed,
#: keyed by its declaration (or class)
_SOURCES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
#: modules imported from files, by resolved path: (sha256, module)
_FILES: dict[str, tuple[str, Any]] = {}


def _key(model: AbstractModel):
    """What identifies a model's definition: its declaration, or its class (held parameters
    and integration settings aside)."""
    model = model.unfixed
    return model.declaration if isinstance(model, Model) else type(model)


def _entry_points() -> dict[str, EntryPoint]:
    try:
        return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}
    except Exception:  # a broken installation must not break the built-in models
        return {}


def names() -> tuple[str, ...]:
    """Every model name mrjax knows: the paper's, the literature models, those registered in
    this process, then those of installed packages (entry-point group `mrjax.models`)."""
    out = list(_BUILTIN) + list(LITERATURE) + list(_USER)
    out += [n for n in _entry_points() if n not in out]
    return tuple(out)


def aliases() -> dict[str, str]:
    """Other names accepted by :func:`get`: alias -> registered name (`tanh` -> `kwok`, ...)."""
    return dict(_ALIASES)


def is_spec(text: str) -> bool:
    """Whether `text` names a model by its place: `path/file.py[:Name]` or `module:Name`."""
    return ":" in text or text.endswith(".py")


def get(name: str | AbstractModel | type, *, substeps: int | None = None,
        fixed: Mapping[str, float] | None = None) -> AbstractModel:
    """The model called `name`.

    **Arguments:**

    - `name`: a registered name (`bingham`, `kwok`, `bouc_wen`, `modified_bouc_wen`, `dahl`,
        the literature models `lugre`, `herschel_bulkley`, `polynomial`, aliases `tanh`,
        `spencer`; models registered with :func:`register` or installed through the
        `mrjax.models` entry points), a place `"path/to/file.py:Name"` or
        `"package.module:Name"` (the file's only model if `:Name` is left out), a model
        instance (returned as is) or a model class.
    - `substeps`: fixed RK4 sub-steps per sample for ODE models (`None`: automatic).
    - `fixed`: parameters to hold at values, name -> value [SI units] (`mrjax.models.fix`).

    Raises :class:`mrjax.InputError` for an unknown name or a place that does not give a model,
    or a bad `fixed` (see `mrjax.models.fix`).
    """
    if isinstance(name, AbstractModel):
        model = name
    elif isinstance(name, type) and issubclass(name, AbstractModel):
        model = name()
    else:
        text = str(name).strip()
        model = load(text) if is_spec(text) else _by_name(text)
    if fixed:
        model = fix(model, fixed)
    return model if substeps is None else model.with_substeps(substeps)


def _by_name(text: str) -> AbstractModel:
    key = text.lower().replace("-", "_")
    key = _ALIASES.get(key, key)
    if key in _BUILTIN:
        return _BUILTIN[key]()
    if key in LITERATURE:
        if key not in _LITERATURE_CACHE:
            _LITERATURE_CACHE[key] = LITERATURE[key]()
        return _LITERATURE_CACHE[key]
    if key in _USER:
        return _USER[key]
    eps = _entry_points()
    if key in eps:
        return _load_entry_point(eps[key])
    close = difflib.get_close_matches(key, [*names(), *_ALIASES], n=1, cutoff=0.6)
    hint = f"did you mean {close[0]!r}? " if close else ""
    raise InputError(f"unknown model {text!r}; {hint}choose one of {', '.join(names())} "
                     f"(aliases: {', '.join(_ALIASES)}), or give path/to/file.py:Name")


def register(model: AbstractModel | type, *, source: Mapping[str, Any] | None = None
             ) -> AbstractModel:
    """Register a model under its name, so that `get(name)`, `mrjax.fit(name, ...)` and the
    lists of :func:`names` find it; registering a name again replaces the earlier model.

    **Arguments:** `model` a model instance (e.g. a `mrjax.models.Model`) or an
    `AbstractModel` subclass; `source` where it came from (default: found from the module that
    defines it, see :func:`source_of`).

    **Returns:** the registered model. Raises :class:`mrjax.InputError` for a name that
    collides with a built-in model.
    """
    model = _as_model(model, "register")
    name = model.name
    if name in reserved_names() and _provenance_module(model).split(".")[0] != "mrjax":
        raise InputError(f"model name {name!r} collides with a built-in model of mrjax; choose "
                         f"another name")
    _USER[name] = model
    if source is not None:
        _SOURCES[_key(model)] = (dict(source), dict(model.fixed))
    return model


def unregister(name: str) -> None:
    """Forget a model registered in this process (:func:`register`, or loaded from a file,
    module or entry point); the built-in models stay. Unknown names are ignored."""
    _USER.pop(str(name).strip().lower(), None)


def _as_model(value: Any, where: str) -> AbstractModel:
    if isinstance(value, AbstractModel):
        return value
    if isinstance(value, type) and issubclass(value, AbstractModel):
        return value()
    raise InputError(f"{where}: got {type(value).__name__} {value!r:.60}, not an mrjax model "
                     f"(mrjax.models.Model or an AbstractModel subclass)")


def _provenance_module(model: AbstractModel) -> str:
    model = model.unfixed
    if isinstance(model, Model):
        return getattr(model.declaration.force_fn, "__module__", "") or ""
    return type(model).__module__


# ------------------------------------------------------------------------------ places
def load(spec: str) -> AbstractModel:
    """The model at `spec`: `"path/to/file.py:Name"`, `"path/to/file.py"` (its only model)
    or `"package.module:Name"`; it is registered under its name (see :func:`register`), with
    its source (file and SHA-256, or module).

    Raises :class:`mrjax.InputError` (one line) for a file that is missing or does not
    import, a missing name, or an object that is not a model.
    """
    target, sep, obj = spec.rpartition(":") if ":" in spec else (spec, "", "")
    if not target:
        raise InputError(f"model {spec!r}: give path/to/file.py:Name or package.module:Name")
    obj = obj.strip()
    if target.endswith(".py") or "/" in target or "\\" in target:
        path = Path(target).expanduser().resolve()
        module, sha = _import_file(path, spec)
        source = {"kind": "file", "file": str(path), "object": obj, "sha256": sha}
    else:
        try:
            module = importlib.import_module(target)
        except Exception as e:
            raise InputError(f"model {spec!r}: module {target!r} does not import: "
                             f"{_one_line(e)}") from None
        source = {"kind": "module", "module": target, "object": obj}
        source.update(_file_of(module))
    if not obj:
        found = [k for k, v in vars(module).items() if not k.startswith("_") and (
            isinstance(v, AbstractModel) or (isinstance(v, type) and issubclass(
                v, AbstractModel) and v.__module__ == module.__name__))]
        if len(found) != 1:
            raise InputError(f"model {spec!r}: the file defines {len(found)} models "
                             f"({', '.join(found) or 'none'}); name one as {target}:NAME")
        obj = source["object"] = found[0]
    if not hasattr(module, obj):
        have = [k for k, v in vars(module).items() if isinstance(v, AbstractModel)]
        raise InputError(f"model {spec!r}: {target} has no {obj!r}"
                         + (f" (its models: {', '.join(have)})" if have else ""))
    model = _as_model(getattr(module, obj), f"model {spec!r}")
    return register(model, source=source)


def _one_line(e: BaseException) -> str:
    msg = str(e).strip().splitlines()
    return type(e).__name__ + (f": {msg[0]}" if msg else "")


def _import_file(path: Path, spec: str):
    """Import the Python file at `path` once per content (module name
    `mrjax_user_<stem>_<sha8>`); returns `(module, sha256)`."""
    if not path.is_file():
        raise InputError(f"model {spec!r}: file {str(path)!r} not found")
    data = path.read_bytes()
    sha = hashlib.sha256(data).hexdigest()
    done = _FILES.get(str(path))
    if done is not None and done[0] == sha:
        return done[1], sha
    stem = "".join(c if c.isalnum() else "_" for c in path.stem)
    mod_name = f"mrjax_user_{stem}_{sha[:8]}"
    spec_obj = importlib.util.spec_from_file_location(mod_name, path)
    if spec_obj is None or spec_obj.loader is None:
        raise InputError(f"model {spec!r}: {str(path)!r} is not a Python file")
    module = importlib.util.module_from_spec(spec_obj)
    sys.modules[mod_name] = module
    try:
        spec_obj.loader.exec_module(module)
    except InputError as e:  # a bad declaration inside the file: its own line
        sys.modules.pop(mod_name, None)
        raise InputError(f"{path.name}: {e}") from None
    except Exception as e:
        sys.modules.pop(mod_name, None)
        raise InputError(f"model file {str(path)!r} does not import: {_one_line(e)}") from None
    _FILES[str(path)] = (sha, module)
    return module, sha


def _file_of(module) -> dict[str, str]:
    f = getattr(module, "__file__", None)
    if not f or not Path(f).is_file():
        return {}
    return {"file": str(Path(f).resolve()),
            "sha256": hashlib.sha256(Path(f).read_bytes()).hexdigest()}


def _load_entry_point(ep: EntryPoint) -> AbstractModel:
    dist = getattr(ep, "dist", None)
    source = {"kind": "entry_point", "group": ENTRY_POINT_GROUP, "name": ep.name,
              "value": ep.value, "distribution": getattr(dist, "name", None),
              "version": getattr(dist, "version", None)}
    try:
        value = ep.load()
    except InputError as e:
        raise InputError(f"entry point {ep.name} = {ep.value}: {e}") from None
    except Exception as e:
        raise InputError(f"entry point {ep.name} = {ep.value} does not load: "
                         f"{_one_line(e)}") from None
    model = _as_model(value, f"entry point {ep.name} = {ep.value}")
    if model.name != ep.name:
        raise InputError(f"entry point {ep.name} = {ep.value} gives model {model.name!r}; the "
                         f"entry point's name must be the model's name")
    return register(model, source=source)


# ------------------------------------------------------------------------------ sources
def source_of(model: AbstractModel) -> dict[str, Any]:
    """Where `model` came from, as fit.json records it: `{"kind": "builtin"}` for mrjax's
    own models; `{"kind": "file", "file", "object", "sha256"}`; `{"kind": "module", "module",
    "object", "file", "sha256"}`; `{"kind": "entry_point", "name", "value", "distribution",
    "version"}`; or `{"kind": "session", "module"}` for a model defined where no other process
    can import it (a script run as `__main__`, a notebook). With `"fixed": {name: value}` where
    the model, or the object found there, holds parameters (`mrjax.models.fix`):
    :func:`from_source` then rebuilds exactly this model."""
    where, held_there = _where_from(model)
    if model.fixed or held_there:
        where["fixed"] = dict(model.fixed)
    return where


def _where_from(model: AbstractModel) -> tuple[dict[str, Any], dict[str, float]]:
    """Where `model`'s definition came from, and the parameters the model object found there
    holds fixed."""
    key = _key(model)
    if key in _BUILTIN.values() or model.name in LITERATURE and \
            _provenance_module(model).startswith("mrjax."):
        return {"kind": "builtin"}, {}
    known = _SOURCES.get(key)
    if known is not None:
        return dict(known[0]), dict(known[1])
    mod_name = _provenance_module(model)
    module = sys.modules.get(mod_name)
    if module is None or mod_name == "__main__" or mod_name.startswith("mrjax_user_") or \
            not getattr(module, "__file__", None):
        return {"kind": "session", "module": mod_name}, {}
    found = [(k, v) for k, v in vars(module).items() if (
        isinstance(v, AbstractModel) and _key(v) is key) or v is key]
    if not found:
        return {"kind": "session", "module": mod_name}, {}
    obj, value = found[0]
    held = dict(value.fixed) if isinstance(value, AbstractModel) else {}
    return {"kind": "module", "module": mod_name, "object": obj, **_file_of(module)}, held


def describe_source(source: Mapping[str, Any]) -> str:
    """One line saying where a model came from (see :func:`source_of`)."""
    kind = source.get("kind")
    held = source.get("fixed") or {}
    tail = ("; " + ", ".join(f"{n} = {v:g}" for n, v in held.items()) + " fixed") if held \
        else ""
    if kind == "builtin":
        return "built-in" + tail
    if kind == "file":
        return f"file {source.get('file')}:{source.get('object')}" + tail
    if kind == "module":
        return f"module {source.get('module')}:{source.get('object')}" + tail
    if kind == "entry_point":
        dist = source.get("distribution")
        return (f"entry point {source.get('value')}"
                + (f" ({dist} {source.get('version') or ''})".rstrip() if dist else "") + tail)
    return f"this session ({source.get('module')})" + tail


def from_source(name: str, source: Mapping[str, Any] | None = None, *,
                fixed: Mapping[str, float] | None = None) -> AbstractModel:
    """The model called `name` that fit.json says came from `source` (see :func:`source_of`),
    found again in this process: a built-in, a registered or installed model, or the module or
    file recorded (a file whose content changed since gives a warning); with the parameters
    held that `fixed` (default: the source's `"fixed"`) names, exactly those.

    Raises :class:`mrjax.InputError` in one line saying what to pass when it cannot.
    """
    source = dict(source or {})
    held = fixed if fixed is not None else source.get("fixed")
    model = _found_again(name, source)
    return model if held is None else fix(model.unfixed, held)


def _found_again(name: str, source: dict[str, Any]) -> AbstractModel:
    key = str(name).strip().lower()
    kind = source.get("kind")
    if key in reserved_names() or key in _USER or key in _entry_points():
        return get(key)
    stem = Path(str(source.get("file") or "file.py")).name if kind == "file" else "file.py"
    hint = (f"pass the model: --model path/to/{stem}:{source.get('object') or 'NAME'} "
            f"(model= in Python)")
    where = describe_source(source) if kind else "an unrecorded place"
    if kind == "file":
        path = Path(str(source.get("file")))
        if not path.is_file():
            raise InputError(f"model {name!r} came from {path}, which is not there; {hint}")
        model = load(f"{path}:{source.get('object') or ''}".rstrip(":"))
        sha = hashlib.sha256(path.read_bytes()).hexdigest()
        if source.get("sha256") and sha != source["sha256"]:
            warnings.warn(f"model {name!r}: {path} changed since the fit (SHA-256 "
                          f"{str(source['sha256'])[:12]}... then, {sha[:12]}... now)",
                          stacklevel=3)
    elif kind == "module":
        try:
            model = load(f"{source.get('module')}:{source.get('object')}")
        except InputError as e:
            raise InputError(f"model {name!r} came from {where}, which does not load ({e}); "
                             f"{hint}") from None
    else:
        raise InputError(f"model {name!r} is not a model of this installation and came from "
                         f"{where}; {hint}")
    if model.name != key:
        raise InputError(f"model {name!r} came from {where}, which now gives model "
                         f"{model.name!r}; {hint}")
    return model

