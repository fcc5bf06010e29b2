"""Calibrated blur synthesis: render blur along the model's trajectories, heat maps,
photometry, gyro sources, the paper's approximation, and the training-triplet dataset.

Modules: :mod:`~blurtrack.synth.render` (exact blur), :mod:`~blurtrack.synth.paper` (the source
paper's approximation), :mod:`~blurtrack.synth.photometry`, :mod:`~blurtrack.synth.motion`
(gyro sources), :mod:`~blurtrack.synth.perturb` (calibration error for heat maps),
:mod:`~blurtrack.synth.images`, :mod:`~blurtrack.synth.triplet`, :mod:`~blurtrack.synth.dataset`
and :mod:`~blurtrack.synth.predict` (heat maps of a recording). See docs/synthesis.md.
"""
