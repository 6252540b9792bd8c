"""Models from outside the package, for ``sparse-brdf bench`` (docs/bench-guide.md)."""
