"""Files, safely: atomic writes (:mod:`.atomic`), lossless dataclass .npz files
(:mod:`.npz`), per-frame arrays on disk for long clips (:mod:`.framestore`),
all-or-nothing output folders (:mod:`.staging`), and video: the one decoder every stage
uses (:mod:`.video_input`) and the streaming H.264 writer (:mod:`.video_output`)."""
