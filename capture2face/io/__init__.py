"""Files, safely: atomic writes (:mod:`.atomic`), lossless dataclass .npz files
(:mod:`.npz`), per-frame arrays on disk for long clips (:mod:`.framestore`) and
all-or-nothing output folders (:mod:`.staging`)."""
