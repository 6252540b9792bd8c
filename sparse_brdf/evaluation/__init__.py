"""Measuring models in scenes: rendering, SNR in two forms, scenes and images.

- ``render``: Mitsuba renders with materials swapped in, object masks and the noise
  floor.
- ``scenes``: finding scenes, scene specs and their XML.
- ``images``: EXR files, previews and masks.

The bench that compares models with these renders is :mod:`sparse_brdf.benchmark`.
"""

__all__ = ["images", "render", "scenes"]
