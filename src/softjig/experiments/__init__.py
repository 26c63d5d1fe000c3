"""Whole runs on the simulated jig, above the libraries they compose (sim, io, sensing, calibration,
evaluation): the paper's experiment (:mod:`softjig.experiments.paper`, ``softjig demo``) and the methods
compared on a sweep dataset (:mod:`softjig.experiments.compare`, ``softjig compare``)."""
