"""Exceptions raised by sparse-brdf; each message names the file or parameter and the problem."""


class SparseBRDFError(Exception):
    """Base class of every error this package raises on purpose."""


class BRDFFileError(SparseBRDFError, ValueError):
    """A BRDF or coefficient file is missing, truncated, corrupt or of a foreign format."""


class EnsembleMismatchError(SparseBRDFError, ValueError):
    """A coefficient file was encoded with another ensemble than the one given."""


class InvalidBRDFError(SparseBRDFError, ValueError):
    """BRDF values are unusable (NaN/inf, wrong shape, no valid bins)."""


class MissingDataError(SparseBRDFError, FileNotFoundError):
    """Data a scene or corpus needs is not on this machine (e.g. the paper's Grace
    Cathedral map, which is not redistributable and is read from the shared data folder)."""
