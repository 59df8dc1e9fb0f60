"""How a run executes: threaded stage overlap (:mod:`.overlap`), malloc settings that keep
long runs' memory flat (:mod:`.heap`), the cores this process may use (:mod:`.cores`) and
the ``capture2face`` logger with its warning collector (:mod:`.log`)."""
