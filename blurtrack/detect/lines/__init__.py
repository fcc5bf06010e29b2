"""Centre-line measurement of one streak: from a frame's components to measured lines.

Modules in pipeline order: :mod:`~blurtrack.detect.lines.ragged` (batches of polylines stored
ragged), :mod:`~blurtrack.detect.lines.segment` (threshold, components, coarse centre lines),
:mod:`~blurtrack.detect.lines.skeleton` (folded, crossing and looped streaks),
:mod:`~blurtrack.detect.lines.sampling` (batched image sampling along polylines),
:mod:`~blurtrack.detect.lines.centreline` (sub-pixel centre lines and profiles),
:mod:`~blurtrack.detect.lines.gaps` (streaks touching end to end),
:mod:`~blurtrack.detect.lines.normal` (the normal CDF),
:mod:`~blurtrack.detect.lines.shortfit` (endpoints of short streaks),
:mod:`~blurtrack.detect.lines.endpoints` (sub-pixel endpoints from profiles),
:mod:`~blurtrack.detect.lines.measure` (measuring a set of lines).
"""
