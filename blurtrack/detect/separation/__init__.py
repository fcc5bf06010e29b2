"""Touching and crossing streaks: template separation of a frame's merged components.

Modules in pipeline order: :mod:`~blurtrack.detect.separation.consensus` (a frame's shape
consensus), :mod:`~blurtrack.detect.separation.quality` (the per-streak quality flag and its
reason), :mod:`~blurtrack.detect.separation.templates` (a clean
streak as a template), :mod:`~blurtrack.detect.separation.pursuit` (matching pursuit of one
template over a component), :mod:`~blurtrack.detect.separation.refit` (joint refinement of
overlapping placements), :mod:`~blurtrack.detect.separation.mosaic` (each placement's own
image), :mod:`~blurtrack.detect.separation.modal` (references from whole
components), :mod:`~blurtrack.detect.separation.separate` (the separation itself),
:mod:`~blurtrack.detect.separation.anchored` (the modal template placed on fragments).
"""
