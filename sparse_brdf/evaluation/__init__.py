"""Measuring models: rendering, SNR in two forms, the bench and its report.

- ``render``: scenes, Mitsuba renders, EXR I/O, object masks and the noise floor.
- ``bench``: the resumable material x model x scene harness; ``report``,
  ``html_report``: its tables, charts, CSV and HTML page; ``results_file``: the results
  schema; ``ranking``: several results files in one table; ``speed``: evaluation
  throughput; ``stability``: inputs where models fail.
- ``acquisition_bench``, ``acquisition_report``: fits from N samples, rendered against
  the full table.
- ``batch``: encoding files and folders (the command line's file layer).
"""

__all__ = ["acquisition_bench", "acquisition_report", "batch", "bench", "html_report",
           "ranking", "render", "report", "results_file", "speed", "stability"]
