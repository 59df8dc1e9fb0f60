"""How a run executes: threaded stage overlap (:mod:`.overlap`) and malloc settings that
keep long runs' memory flat (:mod:`.heap`)."""
