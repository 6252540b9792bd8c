"""What the three BSDFs share: a single-sided glossy reflector (``GlossyReflection |
FrontSide``) with cosine or lobe sampling, whose ``eval`` is ``BRDF * cos(theta_o)``, and
the variants' colours (rgb, mono, spectral, polarized).

A Python BSDF must derive from the *variant's* ``mi.BSDF``, which exists only once a
variant is set, and nanobind allows a Python class one base only. So :class:`GlossyBSDF`
and the BSDFs built on it (:mod:`~mitsuba_plugin.tabulated`, :mod:`~mitsuba_plugin.sparse`,
:mod:`~mitsuba_plugin.neural`) are written against no base, and
:func:`~mitsuba_plugin.registration.make_classes` copies their bodies onto subclasses of
one variant's ``mi.BSDF``. The variant reaches the methods as class attributes (``_m``,
the variant's names; ``_ops``, its :class:`~mitsuba_plugin.kernels.Ops`; ``_flags``,
``_kind``, ``_polarized``, ``_upsampling`` and a few constants).
"""

from __future__ import annotations

import drjit as dr

from sparse_brdf.decoders.lobe import fit_lobe

from .kernels import lobe_pdf, power_cosine_sample


class GlossyBSDF:
    """What the BSDFs share: a single-sided glossy reflector (``GlossyReflection |
    FrontSide``) with cosine or lobe sampling, whose ``eval`` is ``BRDF * cos(theta_o)``.

    Subclasses set ``plugin``, read their properties and call :meth:`_setup_sampling` in
    ``__init__``, and define ``_rho(wi, wo, active)``, the BRDF's RGB value. Written
    against no base class: see the module docstring and
    :func:`~mitsuba_plugin.registration.make_classes`.
    """

    plugin = "?"

    def __init__(self, props) -> None:
        self._m.BSDF.__init__(self, props)
        self.m_flags = self._flags
        self.m_components = [self._flags]
        if self._kind == "spectral":
            self._upsampling()  # a missing or corrupt table fails at load, not in a render

    def _setup_sampling(self, sampling: str, profile, shape) -> None:
        self.sampling = sampling
        n, p = fit_lobe(profile, shape) if sampling == "lobe" else (1.0, 0.0)
        self.lobe_exponent, self.lobe_prob = float(n), float(p)
        self._exp = self._ops.f(n)
        self._prob = self._ops.f(p)

    def _rho(self, wi, wo, active):  # pragma: no cover - abstract
        raise NotImplementedError

    def _colour(self, rgb, si):
        """The variant's value of the linear-RGB BRDF value ``rgb`` (a Color3f): itself
        in rgb variants, its luminance (``mi.luminance``) in mono ones, its spectrum at
        ``si.wavelengths`` in spectral ones (:class:`~mitsuba_plugin.kernels.
        SpectralUpsampling`). A Python branch at trace time: rgb kernels are unchanged."""
        if self._kind == "rgb":
            return rgb
        if self._kind == "mono":
            return self._m.UnpolarizedSpectrum(self._m.luminance(rgb))
        return self._upsampling().spectrum(rgb, si.wavelengths)

    def _out(self, value):
        """``value`` (an UnpolarizedSpectrum) as the variant's Spectrum: in polarized
        variants a depolarizing Mueller matrix (``mi.depolarizer``), which needs no
        rotation between the local and world frames."""
        return self._m.depolarizer(value) if self._polarized else value

    def _pdf(self, wi, wo, lobe=None):
        """The sampling density of ``wo``; ``lobe``: the lobe's (exponent, probability)
        per lane (a library's, :meth:`_lobe`), else the material's."""
        m = self._m
        ci = m.Frame3f.cos_theta(wi)
        co = m.Frame3f.cos_theta(wo)
        p = m.warp.square_to_cosine_hemisphere_pdf(wo)
        if self.sampling == "lobe":
            n, prob = (self._exp, self._prob) if lobe is None else lobe
            p = (1.0 - prob) * p + prob * lobe_pdf(self._ops, wi, wo, n)
        return dr.select((ci > 0.0) & (co > 0.0), p, 0.0)

    # per-lane materials (a library, :mod:`~mitsuba_plugin.library`) ---------------------
    #: Whether the material varies per lane: then ``_material(si, active)`` gives what
    #: each lane reads (a library's material index), and ``_lobe(mat)`` and
    #: ``_rho_at(mat, wi, wo, active)`` replace the material's own lobe and ``_rho``.
    #: A Python branch: the other BSDFs trace and run as before.
    per_lane = False

    def _material(self, si, active):  # pragma: no cover - abstract
        raise NotImplementedError

    def _lobe(self, mat):  # pragma: no cover - abstract
        raise NotImplementedError

    def _rho_at(self, mat, wi, wo, active):  # pragma: no cover - abstract
        raise NotImplementedError

    # Mitsuba interface ---------------------------------------------------------------
    def sample(self, ctx, si, sample1, sample2, active=True):
        m, zero = self._m, self._zero_s
        bs = dr.zeros(m.BSDFSample3f)
        if not ctx.is_enabled(m.BSDFFlags.GlossyReflection):
            return bs, self._out(zero)
        wi = si.wi
        mat = self._material(si, active) if self.per_lane else None
        lobe = None if mat is None or self.sampling != "lobe" else self._lobe(mat)
        wo = m.warp.square_to_cosine_hemisphere(sample2)
        if self.sampling == "lobe":
            n, prob = (self._exp, self._prob) if lobe is None else lobe
            h = power_cosine_sample(self._ops, sample2, n)
            wo_lobe = 2.0 * dr.dot(wi, h) * h - wi
            wo = dr.select(sample1 < prob, wo_lobe, wo)
        pdf = self._pdf(wi, wo, lobe)
        bs.wo = wo
        bs.pdf = pdf
        bs.eta = 1.0
        bs.sampled_type = m.UInt32(self._glossy)
        bs.sampled_component = m.UInt32(0)
        co = m.Frame3f.cos_theta(wo)
        ok = active & (m.Frame3f.cos_theta(wi) > 0.0) & (co > 0.0) & (pdf > 0.0)
        rgb = self._rho(wi, wo, ok) if mat is None else self._rho_at(mat, wi, wo, ok)
        f = self._colour(rgb, si)
        weight = f * (co / dr.maximum(pdf, 1e-30))
        return bs, self._out(dr.select(ok, weight, zero))

    def eval(self, ctx, si, wo, active=True, mat=None):
        m, zero = self._m, self._zero_s
        if not ctx.is_enabled(m.BSDFFlags.GlossyReflection):
            return self._out(zero)
        co = m.Frame3f.cos_theta(wo)
        ok = active & (m.Frame3f.cos_theta(si.wi) > 0.0) & (co > 0.0)
        if self.per_lane:
            mat = self._material(si, active) if mat is None else mat
            rgb = self._rho_at(mat, si.wi, wo, ok)
        else:
            rgb = self._rho(si.wi, wo, ok)
        f = self._colour(rgb, si)
        return self._out(dr.select(ok, f * co, zero))

    def pdf(self, ctx, si, wo, active=True, mat=None):
        if not ctx.is_enabled(self._m.BSDFFlags.GlossyReflection):
            return self._m.Float(0.0)
        lobe = None
        if self.per_lane and self.sampling == "lobe":
            lobe = self._lobe(self._material(si, active) if mat is None else mat)
        return dr.select(active, self._pdf(si.wi, wo, lobe), 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        mat = self._material(si, active) if self.per_lane else None  # read once for both
        return self.eval(ctx, si, wo, active, mat), self.pdf(ctx, si, wo, active, mat)

    def traverse(self, callback):
        # the material is read-only: nothing to expose for differentiation
        pass

    def parameters_changed(self, keys=None):
        pass
