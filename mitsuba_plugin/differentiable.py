"""Differentiable coefficient values of ``sparse_brdf``: the data of the derivative
carrier.

Both decoders' buffers are linear in the values, but a buffer derived from a parameter
outside a render (as the grouped decoder's contracted tables would be) breaks Mitsuba's
forward mode: the render may only differentiate through variables it reads itself. So
after ``params.update()`` the buffers are rebuilt exactly as from a file holding the
new values (detached), and when a channel's values carry gradients the kernel adds, per
channel, ``sum_t (s_t - detach(s_t)) U1[i, a_t] U2[j, b_t] U3[k, c_t]``: zero in value,
with the model's exact derivative, ``s_t`` gathered inside the kernel from the values
Mitsuba's ``mi.traverse`` holds (see :func:`mitsuba_plugin.bsdfs.strict_x`).
"""

from __future__ import annotations

import numpy as np

from sparse_brdf.model.layouts import channel_terms, strict_channel


def strict_orders(model, ensemble) -> list[np.ndarray]:
    """Per channel, the order in which the strict decoder holds its terms (its term i is
    the file's term ``order[i]``), read off
    :func:`~sparse_brdf.model.layouts.strict_channel` built with the values 0, 1, 2, ...
    so that the order stays defined in one place."""
    out = []
    for c in range(3):
        s, modes, us = channel_terms(model, ensemble, c)
        probe = np.arange(s.size, dtype=np.float32)
        out.append(strict_channel(probe, modes, us).values.astype(np.int64))
    return out
