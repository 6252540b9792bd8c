"""Fitting a material to what a renderer shows.

- ``fit_images``: a sparse BRDF fitted to photographs or renders of known scenes
  (its function :func:`~sparse_brdf.fitting.fit_images.fit_images`).
- ``fit_scene``: the smallest coefficient count (or byte budget) that reaches a target
  rendering SNR in a scene (:func:`~sparse_brdf.fitting.fit_scene.fit_scene`).

Both functions share their modules' names, so the package binds neither; ``__all__``
names the modules.
"""

__all__ = ["fit_images", "fit_scene"]
