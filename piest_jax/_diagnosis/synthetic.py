"""Plain sample-by-sample filters for the hidden-effect generator's physical forms.

They are written as loops on purpose: the generator's truth should not share its discretisation
with the diagnosis model that has to find it (the model's filters are exact for inputs linear
between samples; these are a recursive low-pass and a semi-implicit Euler integration).
"""

import numpy as np


def lowpass(v, a):
    """y_t = a y_{t-1} + (1 - a) v_t, starting at v_0."""
    out = np.empty_like(v)
    s = v[0]
    for i, vi in enumerate(v):
        s = a * s + (1 - a) * vi
        out[i] = s
    return out


def second_order(v, wn, zeta, dt):
    """v through w^2/(s^2 + 2 zeta w s + w^2), semi-implicit Euler on a fine grid, from rest at v_0."""
    sub = max(int(np.ceil(wn * dt / 0.05)), 1)
    h = dt / sub
    x, xd = v[0], 0.0
    out = np.empty_like(v)
    prev = v[0]
    for i, vi in enumerate(v):
        for k in range(sub):  # the input interpolated linearly within the step
            vk = prev + (k + 1) / sub * (vi - prev)
            xd += h * (wn**2 * (vk - x) - 2 * zeta * wn * xd)
            x += h * xd
        out[i] = x
        prev = vi
    return out
