"""Evaluate a GLSL function over NumPy inputs with transform feedback (tests of the shader
library against its NumPy mirror)."""

from __future__ import annotations

import moderngl
import numpy as np

from capture2face.render.context import gl_context
from capture2face.render.shaders import _read

_GLSL_TYPES = {1: "float", 2: "vec2", 3: "vec3", 4: "vec4"}


def eval_glsl(library: str, expression: str, inputs: dict[str, np.ndarray], out_components: int) -> np.ndarray:
    """Run ``expression`` (GLSL over inputs ``a``, ``b``, ...) once per row of the inputs.

    Args:
        library: shader file in ``shaders/`` that defines the functions used.
        expression: e.g. ``"pd_decode(pd_encode(a))"``.
        inputs: name -> (N, C) float arrays, C in 1..4.
        out_components: components of the expression's value (1..4).
    Returns:
        (N, out_components) float32.
    """
    ctx = gl_context()
    decls = "".join(f"in {_GLSL_TYPES[v.shape[1]]} {k};\n" for k, v in inputs.items())
    src = (
        "#version 330 core\n" + _read(library) + decls
        + f"out {_GLSL_TYPES[out_components]} result;\nvoid main() {{ result = {expression}; }}\n"
    )
    prog = ctx.program(vertex_shader=src, varyings=["result"])
    n = len(next(iter(inputs.values())))
    buffers = [ctx.buffer(np.ascontiguousarray(v, np.float32).tobytes()) for v in inputs.values()]
    out = ctx.buffer(reserve=n * out_components * 4)
    vao = ctx.vertex_array(prog, [(b, f"{v.shape[1]}f", k) for b, (k, v) in zip(buffers, inputs.items())],
                           skip_errors=True)
    fbo = ctx.simple_framebuffer((1, 1))  # Mesa skips draws without a complete framebuffer
    try:
        fbo.use()
        vao.transform(out, moderngl.POINTS, vertices=n)
        return np.frombuffer(out.read(), np.float32).reshape(n, out_components).copy()
    finally:
        for obj in (vao, fbo, out, *buffers, prog):
            obj.release()
