"""Geometry of the gyro-driven blur: camera, rotations, gyro traces, the backend-generic kernels
(:mod:`~blurtrack.geometry.kernels`, one model over numpy and CasADi), :class:`BlurModel`
(:mod:`~blurtrack.geometry.blur_model`) and heat maps. Conventions: docs/conventions.md."""
