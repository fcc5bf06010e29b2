"""Known-truth generators for tests and benchmarks: analytic streak renderers and mini
sessions. The full simulated rig lives in :mod:`rigs.sim`."""
