"""glTF 2.0, in one place: the container (:mod:`.container`, read and written with
pygltflib, accessors decoded in NumPy), a FaceRig's own .glb (:mod:`.rig_export`), a
user's character read into a FaceRig (:mod:`.rig_import`), an animation of our rig
(:mod:`.animation`), the user's own file with the performance (:mod:`.character`), and
the ARKit-character export the tests drive (:mod:`.arkit_export`).

Dependencies run one way: container <- animation <- rig_export, container <- rig_import,
animation <- character.
"""

from capture2face.gltf.container import (
    CM_PER_METRE,
    EXTRAS_FORMAT,
    EXTRAS_KEY,
    METRES_PER_CM,
    ROOT_NODE_NAME,
    SAMPLER_LINEAR_CLAMP,
)
from capture2face.gltf.rig_export import build_rig_gltf, export_glb, import_glb

__all__ = ["export_glb", "import_glb", "build_rig_gltf", "METRES_PER_CM", "CM_PER_METRE", "EXTRAS_KEY",
           "EXTRAS_FORMAT", "ROOT_NODE_NAME", "SAMPLER_LINEAR_CLAMP"]
