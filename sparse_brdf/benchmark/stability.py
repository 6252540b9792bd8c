"""Stability where methods fail: perturbed materials, every method, one status each.

Each case perturbs a clean BRDF and writes it as a MERL file, which is then loaded
through the normal reader (so NaN/inf entries meet the reader's checks, and negative
entries become unmeasured bins, as in real MERL data). Every method fits the loaded
BRDF; the outcome is one of:

- ``finished``: a finite reconstruction; its cosine-weighted SNR (dB) is recorded,
  against the clean BRDF (noise, missing bins) or against the perturbed one (dynamic
  range, near-black), over bins valid in both;
- ``clear error``: a :class:`~sparse_brdf.errors.SparseBRDFError` (or ValueError) whose
  message names the problem, raised before any output;
- ``failed``: any other exception, a NaN/inf reconstruction, or a non-convergence.

One method's failure never stops the suite.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..brdf import BRDF
from ..compared.protocol import ComparedModel, table_of
from ..coords import grid_angles
from ..errors import SparseBRDFError
from ..fileio import atomic_write
from ..metrics import cosine_weighted_snr
from ..sources.merl import MERL_SCALE, read_merl

Perturb = Callable[[np.ndarray, np.ndarray, np.random.Generator], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Case:
    """A perturbation; ``against_clean``: score against the clean BRDF (can the method
    recover the material?) or against the perturbed one (can it represent what it got?)."""

    name: str
    perturb: Perturb  # (values, valid, rng) -> (values (n1, n2, n3, 3), valid)
    against_clean: bool = True


def _noise(level: float) -> Perturb:
    def f(v, valid, rng):
        return v * np.maximum(1 + level * rng.standard_normal(v.shape), 0), valid
    return f


def _missing_random(frac: float) -> Perturb:
    def f(v, valid, rng):
        return v, valid & (rng.random(valid.shape) >= frac)
    return f


def _missing_grazing(deg: float) -> Perturb:
    def f(v, valid, rng):
        _, td, _ = grid_angles(valid.shape)
        return v, valid & (td < np.radians(deg))
    return f


def _scale(s: float) -> Perturb:
    def f(v, valid, rng):
        return v * s, valid
    return f


def _spike(peak: float) -> Perturb:
    """Near-mirror dynamic range: multiply the theta_h < 1 degree bins by ``peak``."""
    def f(v, valid, rng):
        th, _, _ = grid_angles(valid.shape)
        out = v.copy()
        out[th < np.radians(1.0)] *= peak
        return out, valid
    return f


def _poison(value: float, frac: float = 1e-3) -> Perturb:
    def f(v, valid, rng):
        out = v.copy()
        hit = rng.random(v.shape) < frac
        out[hit] = value
        return out, valid
    return f


CASES: tuple[Case, ...] = (
    Case("noise 1%", _noise(0.01)),
    Case("noise 10%", _noise(0.10)),
    Case("noise 50%", _noise(0.50)),
    Case("missing 20% random", _missing_random(0.2)),
    Case("missing grazing > 70 deg", _missing_grazing(70)),
    Case("near-mirror x1e4 peak", _spike(1e4), against_clean=False),
    Case("near-black x1e-5", _scale(1e-5), against_clean=False),
    Case("negative entries", _poison(-1.0)),
    Case("NaN entries", _poison(np.nan)),
    Case("inf entries", _poison(np.inf)),
)


def _write_raw(path: Path, values: np.ndarray, valid: np.ndarray) -> Path:
    """A MERL file with arbitrary (possibly non-finite) values; invalid bins as -1."""
    stored = np.moveaxis(values.astype(np.float64), -1, 0) / MERL_SCALE[:, None, None, None]
    stored = np.where(valid[None], stored, -1.0)
    with atomic_write(path) as f:
        f.write(np.asarray(valid.shape, "<i4").tobytes() + stored.astype("<f8").tobytes())
    return path


def run_stability(
    clean: BRDF,
    methods: Sequence[ComparedModel],
    work: Path,
    cases: Sequence[Case] = CASES,
    seed: int = 0,
) -> list[dict]:
    """Run every case against every method; one row per (case, method)."""
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for ci, case in enumerate(cases):
        rng = np.random.default_rng([seed, ci])
        values, valid = case.perturb(clean.values.copy(), clean.valid.copy(), rng)
        path = _write_raw(work / f"case{ci}.binary", values, valid)
        try:
            brdf = read_merl(path, name=f"{clean.name} [{case.name}]")
            load_error = None
        except (SparseBRDFError, ValueError) as exc:
            brdf, load_error = None, str(exc)
        for m in methods:
            row = {"case": case.name, "method": m.name}
            if brdf is None:
                row.update(status="clear error", message=load_error)
                rows.append(row)
                continue
            try:
                rec = table_of(m.compress(brdf), brdf)
                if not np.all(np.isfinite(rec)):
                    row.update(status="failed", message="NaN/inf in reconstruction")
                else:
                    truth = clean.values if case.against_clean else brdf.values
                    row.update(status="finished", snr=cosine_weighted_snr(
                        truth, rec, clean.valid & brdf.valid))
            except (SparseBRDFError, ValueError) as exc:
                row.update(status="clear error", message=str(exc))
            except Exception as exc:  # noqa: BLE001 - recorded, never propagated
                row.update(status="failed", message=f"{type(exc).__name__}: {exc}")
            rows.append(row)
    return rows


def stability_markdown(rows: list[dict]) -> list[str]:
    methods = list(dict.fromkeys(r["method"] for r in rows))
    cases = list(dict.fromkeys(r["case"] for r in rows))
    cell = {(r["case"], r["method"]): r for r in rows}
    lines = ["| case | " + " | ".join(methods) + " |", "|---" * (len(methods) + 1) + "|"]
    for c in cases:
        out = []
        for m in methods:
            r = cell[(c, m)]
            if r["status"] == "finished":
                out.append(f"{r['snr']:.1f} dB")
            else:
                out.append(r["status"])
        lines.append(f"| {c} | " + " | ".join(out) + " |")
    return lines
