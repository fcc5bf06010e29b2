"""Endpoint-error reports: streak-level errors, CSV tables, figures and a self-contained HTML page.

Independent of ``calib`` and CasADi: the caller passes the calibrations to compare (e.g. the
rig's initial guess and the fitted one). :func:`blurtrack.report.build.build_report` is the entry
point.
"""
