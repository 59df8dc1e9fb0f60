"""``capture2face run``: one clip in, an animated wrinkled character out.

:func:`run` (:mod:`.runner`) checks everything it can before tracking (:mod:`.preflight`),
then runs the stages (:mod:`.stages`: track, retarget, export; :mod:`.render_pass`:
avatar.mp4 and compare.mp4) and writes the report (:mod:`.report`).
Patch names in the module that uses them (e.g. ``capture2face.pipeline.runner.track_stage``):
this package's copies are re-exports.
"""

from __future__ import annotations

from capture2face.character.load import load_character
from capture2face.pipeline.options import (
    OUTPUT_FILES,
    RunOptions,
    options_json,
    run_render_options,
)
from capture2face.pipeline.render_pass import RenderPass, render_stage
from capture2face.pipeline.report import outputs_complete
from capture2face.pipeline.runner import run
from capture2face.pipeline.stages import (
    avatar_head_poses,
    avatar_head_rotations,
    encoder_threads,
    export_stage,
    retarget_stage,
    start_track_workers,
    track_stage,
)

__all__ = ["OUTPUT_FILES", "RenderPass", "RunOptions", "avatar_head_poses", "avatar_head_rotations", "encoder_threads",
           "export_stage", "load_character", "options_json", "outputs_complete", "render_stage", "retarget_stage",
           "run", "run_render_options", "start_track_workers", "track_stage"]
