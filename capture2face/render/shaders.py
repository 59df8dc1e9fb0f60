"""Shader sources (``shaders/*.glsl``) and a cache of linked programs.

A program is keyed by its stage files, its ``#define`` block and the transform-feedback
varyings, so renderers with the same options share one compiled program.
"""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path

import moderngl

from capture2face.render.context import gl_context

SHADER_DIR = Path(__file__).with_name("shaders")
_INCLUDE = re.compile(r'^#include "([\w.]+)"\s*$', re.MULTILINE)


@cache
def _read(name: str) -> str:
    text = (SHADER_DIR / name).read_text()
    return _INCLUDE.sub(lambda m: _read(m.group(1)), text)


def source(name: str, defines: tuple[tuple[str, object], ...] = ()) -> str:
    """``shaders/name`` with ``#include``s resolved and ``defines`` after ``#version``."""
    block = "".join(f"#define {key} {value}\n" for key, value in defines)
    return "#version 330 core\n" + block + _read(name)


_programs: dict[tuple, moderngl.Program] = {}


def program(
    vertex: str,
    fragment: str | None = None,
    defines: tuple[tuple[str, object], ...] = (),
    varyings: tuple[str, ...] = (),
) -> moderngl.Program:
    """The linked program for these stage files and defines (compiled once per process)."""
    key = (vertex, fragment, defines, varyings)
    prog = _programs.get(key)
    if prog is None:
        ctx = gl_context()
        prog = ctx.program(
            vertex_shader=source(vertex, defines),
            fragment_shader=source(fragment, defines) if fragment else None,
            varyings=list(varyings),
        )
        _programs[key] = prog
    return prog
