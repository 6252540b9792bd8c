"""Measuring models: rendering, SNR in two forms, the bench and its report.

- ``render``: scenes, Mitsuba renders, EXR I/O, object masks and the noise floor.
- ``bench``: the resumable material x model x scene harness; ``report``: its tables,
  charts and CSV; ``speed``: evaluation throughput; ``stability``: inputs where models
  fail; ``fit_scene``: the smallest coefficient counts that reach a target SNR in a scene.
"""
