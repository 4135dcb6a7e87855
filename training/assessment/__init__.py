"""Assessment: rollout metrics and model selection (:mod:`.scores`), evaluation on held-out
starts (:mod:`.evaluation`), scaling studies (:mod:`.scaling`), statistics (:mod:`.stats`),
figures (:mod:`.figures`) and baselines."""
