"""Detection over a whole session: the pipeline, which end of each streak is the start, and
the streak table.

Modules in pipeline order: :mod:`~blurtrack.detect.session.pipeline` (every frame's first pass
in workers, the gyro's stages, the table:
:func:`~blurtrack.detect.session.pipeline.detect_session`),
:mod:`~blurtrack.detect.session.orientation` (the gyro, profile and continuity cues, and the
frames' timing), :mod:`~blurtrack.detect.session.cues` (the cues of a session's frames, in
batches and parts for the workers), :mod:`~blurtrack.detect.session.table` (the streak table).
"""
