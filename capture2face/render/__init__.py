"""Rendering: the rig drawn by OpenGL (EGL, headless) with automatic wrinkles, and video
writing. GL stays inside this package.

``Renderer.create_from_options(rig, RenderOptions(...))`` is a context manager;
``renderer.render(FrameState(...))`` returns an (H, W, 3) uint8 sRGB image.
"""

from capture2face.render.heatmap import heatmap
from capture2face.render.renderer import (
    WRINKLE_DRIVERS,
    FrameState,
    Renderer,
    RenderOptions,
)

__all__ = ["FrameState", "RenderOptions", "Renderer", "WRINKLE_DRIVERS", "heatmap"]
