"""The mapping JSON beside a character (``hero.json`` next to ``hero.glb``): read and
checked against its schema once, before anything is imported, into a :class:`Mapping`.

The schema and what each key means: docs/characters.md, "The mapping JSON" (every key
optional). A file that breaks it is refused in one line that names the file and every
wrong field (a metadata file that happens to share the character's name then says so,
rather than failing half-way through the import); keys the schema does not know are
ignored with a warning.
"""

from __future__ import annotations

import difflib
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from capture2face.errors import CaptureError
from capture2face.rig.arkit_names import canonical_arkit
from capture2face.rig.face_rig import ZONE_NAMES
from capture2face.runtime.log import log
from capture2face.topology import N_LANDMARKS

MATERIALS = ("skin", "eye", "mouth", "teeth", "hair")  # materials.MATERIAL_CODES
POSE_KEYS = ("offsets", "positions", "wrinkle_map", "morphs")

# A check returns None when the value is fine, else what it should be ("a number > 0").
Check = Callable[[Any], "str | None"]


def _shown(value: Any) -> str:
    text = repr(value) if not isinstance(value, (dict, list)) else type(value).__name__
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    return text if len(text) <= 40 else text[:37] + "..."


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _is_int(v: Any) -> bool:
    return _is_number(v) and float(v).is_integer()


def _string(v: Any) -> str | None:
    return None if isinstance(v, str) else "a string"


def _positive(v: Any) -> str | None:
    return None if _is_number(v) and v > 0 else "a number > 0"


def _number(v: Any) -> str | None:
    return None if _is_number(v) else "a number"


def _landmark(v: Any) -> str | None:
    return None if _is_int(v) and 0 <= v < N_LANDMARKS else f"a landmark index 0..{N_LANDMARKS - 1}"


def _vertex(v: Any) -> str | None:
    return None if _is_int(v) and v >= 0 else "a vertex index >= 0"


def _material(v: Any) -> str | None:
    return None if isinstance(v, str) and v.lower() in MATERIALS else "one of " + ", ".join(MATERIALS)


def _xyz(v: Any) -> str | None:
    ok = isinstance(v, list) and len(v) == 3 and all(_is_number(x) for x in v)
    return None if ok else "[x, y, z] (three numbers)"


def _zone_row(v: Any) -> str | None:
    ok = isinstance(v, list) and len(v) == len(ZONE_NAMES) and all(_is_number(x) for x in v)
    return None if ok else f"a list of {len(ZONE_NAMES)} numbers"


def _arkit(v: Any) -> str | None:
    return None if isinstance(v, str) and canonical_arkit(v) is not None else "an ARKit blendshape name"


def _table(where: str, value: Any, check: Check, errors: list[str], key_check: Check | None = None) -> None:
    """``value`` must be an object whose values pass ``check`` (and keys ``key_check``)."""
    if not isinstance(value, dict):
        errors.append(f"{where} must be an object, not {_shown(value)}")
        return
    for k, v in value.items():
        if key_check is not None and key_check(_int_key(k)) is not None:
            errors.append(f"{where} key {k!r} must be {key_check(_int_key(k))}")
        wrong = check(v)
        if wrong is not None:
            errors.append(f"{where}[{k!r}] must be {wrong}, not {_shown(v)}")


def _int_key(k: str) -> Any:
    try:
        return int(k)
    except ValueError:
        return k


def _list(where: str, value: Any, check: Check, errors: list[str], length: int | None = None) -> None:
    if not isinstance(value, list) or (length is not None and len(value) != length):
        errors.append(f"{where} must be a list{f' of {length}' if length else ''}, not {_shown(value)}")
        return
    for i, v in enumerate(value):
        wrong = check(v)
        if wrong is not None:
            errors.append(f"{where}[{i}] must be {wrong}, not {_shown(v)}")


def _bone_group(v: Any) -> str | None:
    ok = isinstance(v, list) and all(isinstance(x, str) for x in v)
    return None if ok else "a list of joint names"


def _poses(value: Any, errors: list[str]) -> None:
    if not isinstance(value, dict):
        errors.append(f"poses must be an object, not {_shown(value)}")
        return
    for name, spec in value.items():
        where = f"poses[{name!r}]"
        if not isinstance(spec, dict):
            errors.append(f"{where} must be an object (offsets, positions, wrinkle_map, morphs), not {_shown(spec)}")
            continue
        for key in ("offsets", "positions"):
            if key in spec:
                _table(f"{where}.{key}", spec[key], _xyz, errors)
        if "wrinkle_map" in spec and _string(spec["wrinkle_map"]):
            errors.append(f"{where}.wrinkle_map must be a string, not {_shown(spec['wrinkle_map'])}")
        if "morphs" in spec:
            _table(f"{where}.morphs", spec["morphs"], _number, errors)
        unknown = [k for k in spec if k not in POSE_KEYS]
        if unknown:
            errors.append(f"{where} has unknown keys {', '.join(map(repr, unknown))} "
                          f"(a pose has {', '.join(POSE_KEYS)})")


def _check_key(key: str, value: Any, errors: list[str]) -> None:
    """One top-level key against the schema (the module doc)."""
    if key in ("name", "head_bone"):
        if value is not None and _string(value):
            errors.append(f"{key} must be a string, not {_shown(value)}")
    elif key == "scale":
        if _positive(value):
            errors.append(f"scale must be a number > 0, not {_shown(value)}")
    elif key == "bones":
        _table("bones", value, _landmark, errors)
    elif key == "bone_groups":
        _list("bone_groups", value, _bone_group, errors)
    elif key == "landmark_vertices":
        _table("landmark_vertices", value, _vertex, errors, key_check=_landmark)
    elif key == "materials":
        _table("materials", value, _material, errors)
    elif key == "wrinkle_maps":
        _table("wrinkle_maps", value, _string, errors)
    elif key == "poses":
        _poses(value, errors)
    elif key == "zone_masks":
        _list("zone_masks", value, _string, errors, length=2)
    elif key == "zone_table":
        _table("zone_table", value, _zone_row, errors)
    elif key == "morphs":
        _table("morphs", value, _arkit, errors)


KEYS = ("name", "scale", "head_bone", "bones", "bone_groups", "landmark_vertices", "materials",
        "wrinkle_maps", "poses", "zone_masks", "zone_table", "morphs")


def mapping_errors(data: Any) -> list[str]:
    """Every way ``data`` (a parsed mapping JSON) breaks the schema, one phrase each."""
    if not isinstance(data, dict):
        return [f"the mapping JSON must be an object, not {_shown(data)}"]
    errors: list[str] = []
    for key, value in data.items():
        _check_key(key, value, errors)
    return errors


def check_mapping(data: Any, path: str | os.PathLike) -> None:
    """Refuse a mapping JSON that breaks the schema: one line naming the file and every
    wrong field; warn about keys the schema does not know.

    Raises:
        CaptureError: ``data`` is not an object or a field has the wrong type or range.
    """
    errors = mapping_errors(data)
    if errors:
        raise CaptureError(f"{os.fspath(path)}: not a valid character mapping: {'; '.join(errors)} "
                           "(see docs/characters.md, 'The mapping JSON')")
    unknown = [k for k in data if k not in KEYS]
    if unknown:
        log.warning("%s: ignored keys that a character mapping does not have: %s", os.fspath(path),
                    ", ".join(map(repr, unknown)))


@dataclass(frozen=True)
class Mapping:
    """A checked mapping JSON (docs/characters.md, "The mapping JSON"); every field as the
    file gives it (absent: None or empty). ``directory``: what its relative paths are
    relative to."""

    directory: Path
    path: Path | None = None
    name: str | None = None
    scale: float | None = None
    head_bone: str | None = None
    bones: dict[str, int] = field(default_factory=dict)
    bone_groups: list[list[str]] = field(default_factory=list)
    landmark_vertices: dict[str, int] = field(default_factory=dict)
    materials: dict[str, str] = field(default_factory=dict)
    wrinkle_maps: dict[str, str] = field(default_factory=dict)
    poses: dict[str, dict] = field(default_factory=dict)
    zone_masks: list[str] | None = None
    zone_table: dict[str, list] = field(default_factory=dict)
    morphs: dict[str, str] = field(default_factory=dict)

    @classmethod
    def from_json(cls, data: dict, directory: Path, path: Path | None = None) -> Mapping:
        """A Mapping of ``data`` (a parsed mapping JSON that passed :func:`check_mapping`;
        ``path``: its file, named in what it is told)."""
        return cls(directory=directory, path=path, **{k: data[k] for k in KEYS if k in data})

    def arkit_renames(self) -> dict[str, str]:
        """Morph name -> the canonical ARKit name the mapping gives it."""
        return {str(k): canonical_arkit(str(v)) for k, v in self.morphs.items()}


def load_mapping(glb: str | os.PathLike, mapping_json: str | os.PathLike | None = None) -> Mapping:
    """The mapping of character ``glb``: ``mapping_json``, else the .glb's path with
    ``.json`` where that file exists, else an empty mapping; checked (:func:`check_mapping`).

    Raises:
        CaptureError: ``mapping_json`` is missing, unreadable or breaks the schema.
    """
    glb = Path(glb)
    path = Path(mapping_json) if mapping_json else glb.with_suffix(".json")
    if not path.is_file():
        if mapping_json:
            raise CaptureError(f"{path}: mapping file not found")
        return Mapping(directory=glb.parent)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CaptureError(f"{path}: not a readable mapping JSON ({exc})") from None
    check_mapping(data, path)
    return Mapping.from_json(data, path.parent, path)


def check_mapped_morphs(mapping: Mapping, names: list[str]) -> None:
    """Every morph the mapping's ``morphs`` renames is one of the file's morph targets
    (``names``): a name it lacks (a typo) would be ignored without a word, so it fails in
    one line naming it and the file's closest names.

    Raises:
        CaptureError: the mapping names a morph the character file does not have.
    """
    have = list(dict.fromkeys(str(n) for n in names))
    missing = [str(k) for k in mapping.morphs if str(k) not in have]
    if not missing:
        return
    said = []
    for name in missing:
        close = difflib.get_close_matches(name, have, n=3, cutoff=0.6) or \
            [n for n in have if name.lower() in n.lower()][:3]
        said.append(f"'{name}'" + (f" (closest: {', '.join(map(repr, close))})" if close else ""))
    where = os.fspath(mapping.path) if mapping.path is not None else "the mapping JSON"
    shown = ", ".join(map(repr, have[:8])) + (", ..." if len(have) > 8 else "")
    one = len(missing) == 1
    raise CaptureError(f"{where}: 'morphs' renames {'; '.join(said)}, but the character file has no morph "
                       f"of {'that name' if one else 'those names'} (its {len(have)} morphs: {shown or 'none'})")
