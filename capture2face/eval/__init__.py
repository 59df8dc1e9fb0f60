"""Accuracy and tuning: ``eval synthetic`` against ground truth (:mod:`.synthetic`), ``eval
fidelity`` on real clips (:mod:`.fidelity`), the renderer's speed per wrinkle driver
(:mod:`.render_speed`) and the tracking filters' jitter and lag (:mod:`.filter_tuning`)."""
