"""Measuring models: rendering, SNR in two forms, the bench and its report.

- ``render``: Mitsuba renders with materials swapped in, object masks and the noise
  floor; ``scenes``: finding scenes, scene specs and their XML; ``images``: EXR files,
  previews and masks.
- ``bench``: the resumable material x model x scene harness; ``bench_config``: its
  configurations and their checks; ``report``, ``html_report``: its tables, charts, CSV
  and HTML page; ``results_file``: the results schema; ``ranking``: several results files
  in one table; ``speed``: evaluation throughput; ``stability``: inputs where models fail.
- ``acquisition_bench``, ``acquisition_report``: fits from N samples, rendered against
  the full table.
"""

__all__ = ["acquisition_bench", "acquisition_report", "bench", "bench_config",
           "html_report", "images", "ranking", "render", "report", "results_file",
           "scenes", "speed", "stability"]
