"""glTF 2.0, in one place: the container (:mod:`.container`: accessors and buffers, read
and written with pygltflib, decoded in NumPy), a FaceRig's own .glb (:mod:`.rig_export`),
a user's character read into a FaceRig (:mod:`.rig_import`, whose passes are one module
per glTF concept: :mod:`.mapping`, :mod:`.scene`, :mod:`.skins`, :mod:`.meshes`,
:mod:`.surface`, :mod:`.welding`, :mod:`.morphs`, :mod:`.materials`, :mod:`.textures`,
:mod:`.own_extras`, :mod:`.mapped_rig`), an animation of our rig (:mod:`.animation_export`),
the user's own file with the performance (:mod:`.character`), and the ARKit-character
export the tests drive (:mod:`.arkit_export`).

``import_glb`` here is the raw importer (what the files say);
:func:`capture2face.character.load.import_glb` (``capture2face.import_glb``) adds what
the default avatar lends a character with face bones.
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
