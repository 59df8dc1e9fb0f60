"""Moved to :mod:`capture2face.gltf.rig_export` (one glTF home: :mod:`capture2face.gltf`); this name stays an
alias of that module, so old imports (and patches of its names) keep working."""

import sys

from capture2face.gltf import rig_export as _module

sys.modules[__name__] = _module
