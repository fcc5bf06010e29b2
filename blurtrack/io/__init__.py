"""Files on disk: session folders, calibration files, the streak table, importers of
third-party recordings, shake traces and the atomic writer. Every loader validates what it
reads and raises :class:`blurtrack.errors.BlurTrackError` subclasses with one-line reasons."""
