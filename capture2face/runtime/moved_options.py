"""Options classes that compose others (``RunOptions(render=RenderOptions(size=...))``) keep
the flat keywords and attributes they had before: each still works, with a
``DeprecationWarning`` naming its new place."""

from __future__ import annotations

import copy
import functools
import warnings
from collections.abc import Callable


def _nested_call(owner: object, path: tuple[str, ...]) -> str:
    """``RunOptions(track=TrackOptions(workers=...))`` for ``path`` ("track", "workers")."""
    text, obj, closing = f"{type(owner).__name__}(", owner, ")"
    for name in path[:-1]:
        obj = getattr(obj, name)
        text += f"{name}={type(obj).__name__}("
        closing += ")"
    return f"{text}{path[-1]}=...{closing}"


def get_path(obj: object, path: tuple[str, ...]):
    """The value at ``path`` below ``obj`` (``("track", "landmarker", "face")``)."""
    return functools.reduce(getattr, path, obj)


def set_path(obj: object, path: tuple[str, ...], value) -> None:
    """Sets the value at ``path`` below ``obj``, copying each part on the way down: a part
    given to (and maybe shared by) several options is never changed in place."""
    if len(path) > 1:
        part = copy.copy(getattr(obj, path[0]))
        set_path(part, path[1:], value)
        value = part
    setattr(obj, path[0], value)


def _moved_property(cls_name: str, name: str, path: tuple[str, ...]) -> property:
    new = f"{cls_name}.{'.'.join(path)}"

    def get(self):
        warnings.warn(f"{cls_name}.{name} is deprecated; use {new}", DeprecationWarning, stacklevel=2)
        return get_path(self, path)

    def put(self, value) -> None:
        warnings.warn(f"{cls_name}.{name} is deprecated; use {new}", DeprecationWarning, stacklevel=2)
        set_path(self, path, value)

    return property(get, put, doc=f"Deprecated: :attr:`{new}`.")


def keeps_moved_names(moved: dict[str, tuple[str, ...]]) -> Callable[[type], type]:
    """Class decorator over a dataclass: each old flat name in ``moved`` (name -> its path in
    the composed options) is accepted as a keyword of the constructor and read or set as
    an attribute, with a ``DeprecationWarning``; a flat keyword applies over the part given
    beside it (``TrackOptions(landmarker=l, face=1)``: ``l`` with ``face=1``)."""
    def decorate(cls: type) -> type:
        init = cls.__init__

        @functools.wraps(init)
        def __init__(self, *args, **kwargs):
            flat = {name: kwargs.pop(name) for name in list(kwargs) if name in moved}
            init(self, *args, **kwargs)
            for name, value in flat.items():
                warnings.warn(f"{cls.__name__}({name}=...) is deprecated; use {_nested_call(self, moved[name])}",
                              DeprecationWarning, stacklevel=2)
                set_path(self, moved[name], value)

        cls.__init__ = __init__
        for name, path in moved.items():
            setattr(cls, name, _moved_property(cls.__name__, name, path))
        cls.MOVED = dict(moved)
        return cls
    return decorate
