"""The bench: models compared on materials and scenes, and its reports.

- ``bench``: the resumable material x model x scene harness (the order of the work, and
  its results file); ``cells``: what each cell computes (renders, SNR, HDR-FLIP, speed);
  ``bench_config``: its configurations and their checks.
- ``report``, ``html_report``: its tables, CSV and HTML page; ``charts``: its charts
  (SNR and HDR-FLIP against speed and bytes, error against coefficients); ``results_file``:
  the results schema; ``ranking``: several results files in one table; ``compare``:
  two results compared cell by cell (the regression gate, ``bench-compare``);
  ``provenance``: what each cell was computed from, so a rerun recomputes what changed.
- ``speed``: evaluation throughput; ``stability``: inputs where models fail.
- ``acquisition_bench``, ``acquisition_report``: fits from N samples, rendered against
  the full table.

The renders themselves come from :mod:`sparse_brdf.evaluation`.
"""

__all__ = ["acquisition_bench", "acquisition_report", "bench", "bench_config", "cells", "charts",
           "compare",
           "html_report", "provenance", "ranking", "report", "results_file", "speed",
           "stability"]
