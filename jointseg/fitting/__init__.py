"""Fitting the models the library ships (the learned vote, the up-axis weighing): what the fits
share, the tuning scans, the networks' and geometry's outputs on them, and the provenance record
written beside every fitted model; the up-axis weighing's fit itself (:mod:`.up_axis`, its cases
in :mod:`.up_axis_cases`), which the frame stage that reads the model never imports.

Why in the package: a shipped model must be reproducible by typed, tested code (`jointseg fit`),
not by a benchmark script; ``bench/`` only measures.
"""
