"""Maths with no GL, glTF or files: rotations (:mod:`.rotations`) and small statistics (:mod:`.stats`)."""
