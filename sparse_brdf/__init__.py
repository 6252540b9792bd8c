"""sparse-brdf: measured BRDFs as sparse coefficients over a learned dictionary ensemble.

An implementation of Tongbuasirilai et al., "A Sparse Non-parametric BRDF Model"
(ACM TOG 2022). Data flows one way: load -> transform -> train/encode -> store ->
decode/render -> evaluate.

>>> import sparse_brdf as sb
>>> brdf = sb.load_brdf("mitsuba:au-ggx-0.25")          # (90, 90, 180, 3) linear RGB
>>> model = sb.encode(brdf)                             # shipped ensemble, default size
>>> sb.save_sbrdf("gold.sbrdf", model)                   # at most 1,700 bytes (version 2)
>>> paper = sb.encode(brdf, n_coeffs=262, **sb.PAPER_OPTIONS)  # the paper's model
>>> small = sb.encode(brdf, n_bytes=1000)                # a file of at most 1000 bytes
>>> summary = sb.encode_batch("materials/", "coded/")    # a folder: .sbrdf files, summary
>>> rec = model.decode(sb.Ensemble.default())            # back to a BRDF
>>> net = sb.train_nbrdf(brdf, time_budget=120)          # a Neural-BRDF network (675 floats)
"""

from .acquisition.files import read_samples, write_samples
from .acquisition.measurements import Samples
from .acquisition.pca import pca_from_samples
from .acquisition.planning import plan as plan_samples
from .acquisition.recovery import encode_samples
from .batch import encode_batch
from .brdf import BRDF
from .coding.budget import encode_to_bytes
from .coding.coefficients import SparseBRDF
from .coding.encode import encode
from .coding.ensemble import Ensemble
from .coding.fileformat import decode_file, load_sbrdf, save_sbrdf
from .coding.interpolate import interpolate
from .coding.spec import (
    DEFAULT_N_BYTES,
    DEFAULT_N_COEFFS,
    ENCODE_OPTIONS,
    PAPER_OPTIONS,
    EncodeSpec,
)
from .compared.neural import NeuralFit, train_nbrdf
from .compared.protocol import ComparedModel, CompressedBRDF
from .errors import BRDFFileError, EnsembleMismatchError, InvalidBRDFError, SparseBRDFError
from .metrics import (
    FlipResult,
    SNRForms,
    cosine_weighted_snr,
    gamma_mse,
    hdr_flip,
    rae,
    render_snr,
    snr_forms,
)
from .sources.catalog import mitsuba_catalog
from .sources.corpora import Corpus, Material, get_corpus, list_corpora
from .sources.load import load_brdf
from .sources.merl import read_merl, write_merl
from .training.train import train_dictionaries, train_ensemble
from .transforms import TRANSFORMS
from .transforms import forward as transform
from .transforms import inverse as inverse_transform

__version__ = "0.1.0"

__all__ = [
    "BRDF", "BRDFFileError", "ComparedModel", "CompressedBRDF", "Corpus",
    "DEFAULT_N_BYTES", "DEFAULT_N_COEFFS", "ENCODE_OPTIONS", "EncodeSpec", "Ensemble",
    "EnsembleMismatchError", "FlipResult", "PAPER_OPTIONS",
    "InvalidBRDFError", "Material", "NeuralFit", "SNRForms", "Samples", "SparseBRDF",
    "SparseBRDFError", "TRANSFORMS", "cosine_weighted_snr", "decode_file", "encode",
    "encode_batch", "encode_samples", "encode_to_bytes", "gamma_mse", "hdr_flip",
    "get_corpus",
    "interpolate", "inverse_transform", "list_corpora", "load_brdf", "load_sbrdf",
    "mitsuba_catalog", "pca_from_samples", "plan_samples", "rae", "read_samples",
    "read_merl", "render_snr", "save_sbrdf", "snr_forms", "train_dictionaries", "train_ensemble",
    "train_nbrdf", "transform", "write_merl", "write_samples",
]
