"""A user's character is prepared once (import, landmark cast, baked maps) and read back from
the disk cache while its files' content and the package's code stay the same."""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest

from capture2face.character import load, prepared
from capture2face.gltf.arkit_export import export_arkit_character
from capture2face.rig.arkit_names import is_automatic
from capture2face.rig.avatar import default_avatar


@pytest.fixture
def counted(tmp_path, monkeypatch):
    """A fresh cache folder, no in-process memo, and a count of the preparations."""
    default_avatar()  # built (or read) before the cache folder moves
    monkeypatch.setenv("CAPTURE2FACE_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(load, "_IMPORTED", {})
    built = []
    real = load.import_glb
    monkeypatch.setattr(load, "import_glb", lambda *a, **k: built.append(1) or real(*a, **k))
    return built


def _fresh_process(monkeypatch):
    monkeypatch.setattr(load, "_IMPORTED", {})


def _assert_same_rig(a, b):
    for field in dataclasses.fields(a):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y, err_msg=field.name)
        else:
            assert x == y, field.name


def test_a_character_is_prepared_once_then_read_back(tmp_path, monkeypatch, counted):
    char = tmp_path / "hero.glb"
    export_arkit_character(default_avatar(), char)
    first = load.load_character(char)
    assert counted == [1] and is_automatic(first)
    entries = sorted(p.name for p in prepared.prepared_dir().iterdir())
    assert len(entries) == 2 and entries[0].endswith(".rig.npz") and entries[1].endswith(".said.json")

    _fresh_process(monkeypatch)
    again = load.load_character(char)
    assert counted == [1]  # no import, no landmark render: the prepared copy
    _assert_same_rig(first, again)

    # The same file copied to another folder is the same character (its name is its stem).
    other = tmp_path / "copy" / "hero.glb"
    other.parent.mkdir()
    shutil.copyfile(char, other)
    _fresh_process(monkeypatch)
    load.load_character(other)
    assert counted == [1]


def test_new_content_or_a_new_mapping_prepares_again(tmp_path, monkeypatch, counted):
    char = tmp_path / "hero.glb"
    export_arkit_character(default_avatar(), char)
    load.load_character(char)
    export_arkit_character(default_avatar(), char, naming=".L")  # same path, other bytes
    _fresh_process(monkeypatch)
    load.load_character(char)
    assert counted == [1, 1]

    (tmp_path / "hero.json").write_text('{"name": "renamed"}')  # the mapping counts too
    _fresh_process(monkeypatch)
    assert load.load_character(char).name == "renamed"
    assert counted == [1, 1, 1]


def test_a_damaged_cache_entry_is_prepared_again(tmp_path, monkeypatch, counted):
    char = tmp_path / "hero.glb"
    export_arkit_character(default_avatar(), char)
    first = load.load_character(char)
    for entry in prepared.prepared_dir().glob("*.rig.npz"):
        entry.write_bytes(entry.read_bytes()[:1000])  # cut short (a full disk, a killed copy)
    _fresh_process(monkeypatch)
    again = load.load_character(char)
    assert counted == [1, 1]
    _assert_same_rig(first, again)


def test_an_unwritable_cache_warns_and_still_loads(tmp_path, monkeypatch, counted, caplog):
    char = tmp_path / "hero.glb"
    export_arkit_character(default_avatar(), char)
    blocker = tmp_path / "cache"
    blocker.write_text("a file where the cache folder should be")
    rig = load.load_character(char)
    assert is_automatic(rig) and counted == [1]
    assert any("cannot cache the prepared character" in r.getMessage() for r in caplog.records)


def test_only_the_most_recently_used_entries_stay(tmp_path, monkeypatch, counted):
    monkeypatch.setattr(prepared, "KEEP", 2)
    chars = []
    for k, naming in enumerate(("_L", ".L", "arkit")):
        char = tmp_path / str(k) / "hero.glb"
        char.parent.mkdir()
        export_arkit_character(default_avatar(), char, naming=naming)
        chars.append(char)
    load.load_character(chars[0])
    load.load_character(chars[1])
    _fresh_process(monkeypatch)
    load.load_character(chars[0])  # read back: now the most recent
    load.load_character(chars[2])  # a third: the least recently used (chars[1]) goes
    assert len(list(prepared.prepared_dir().glob("*.rig.npz"))) == 2
    assert len(list(prepared.prepared_dir().glob("*.said.json"))) == 2
    _fresh_process(monkeypatch)
    load.load_character(chars[0])
    assert counted == [1, 1, 1]
    load.load_character(chars[1])
    assert counted == [1, 1, 1, 1]
