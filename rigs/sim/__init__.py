"""Simulated laser-grid rig: true motion, dot renderer, gyro model, session writer.

Import the pieces from their modules (``rigs.sim.rig.SimRig``, ``rigs.sim.preset``,
``rigs.sim.writer.write_session``); this package file stays import-free so that reading one
module does not pull in the renderer.
"""
