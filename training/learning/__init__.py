"""Learning: the config (:mod:`.config`), samples (:mod:`.samples`), the objectives
(:mod:`.objectives`), the training loop (:mod:`.trainer`), the control period (:mod:`.period`),
the ONNX twin and run records."""
