"""Measuring models in scenes: rendering, SNR in two forms, scenes and images.

- ``render``: Mitsuba renders with materials swapped in, object masks and the noise
  floor.
- ``scenes``: finding scenes, scene specs and their XML.
- ``libraries``: a scene's many ``sparse_brdf`` materials written as one
  ``sparse_library``.
- ``images``: EXR files, previews and masks.

The bench that compares models with these renders is :mod:`sparse_brdf.benchmark`.
"""

__all__ = ["images", "libraries", "render", "scenes"]
