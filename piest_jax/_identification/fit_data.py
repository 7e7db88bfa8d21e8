"""A record made ready for fitting: checked, in normalised units, padded to a shared length."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .. import _checks
from .._custom_types import Scalar


class Scales(eqx.Module):
    """The centres and half ranges that map the data's units to normalised ones."""

    u_mid: Scalar
    u_half: Scalar
    y_mid: Scalar
    y_half: Scalar


def pad_count(T: int) -> int:
    """Samples to append so that nearby record lengths share one compiled fit.

    Lengths are rounded up to a multiple of an eighth of the next power of two (at least 512),
    so a compiled solver is reused for records within about 12 % of each other's length.
    """
    return -T % max(512, 2 ** max(int(np.ceil(np.log2(T))) - 3, 0))


def prepare(u, y, n_plays, mask, thresholds0, initial_states, per_play=2, extra=0):
    """Check, normalise and pad one record for fitting.

    **Arguments:** `u`, `y` (T,); `n_plays`; `mask` (T,) of the samples fitted, or None for all;
    `thresholds0`, starting thresholds in the data's units or None; `initial_states`, the plays'
    states before sample 0 or None (relaxed at u_0); `per_play`, parameters per play, and
    `extra`, further parameters (a creep's), for the check that there are enough samples.

    **Returns:** `(un, yn, mask, scales, x0, thresholds0)` in normalised units, padded.
    """
    u = _checks.finite(_checks.signal(u, "u"), "u")
    y = _checks.finite(_checks.signal(y, "y"), "y")
    if u.shape != y.shape:
        raise ValueError(f"`u` has {u.shape[0]} samples but `y` has {y.shape[0]}")
    if not isinstance(n_plays, (int, np.integer)) or n_plays < 1:
        raise ValueError(f"`n_plays` must be a positive whole number, got {n_plays!r}")
    dtype = jnp.result_type(u, y)
    u, y = u.astype(dtype), y.astype(dtype)
    mask_np = np.ones(u.shape, dtype) if mask is None else np.asarray(mask, dtype)
    if mask_np.shape != u.shape:
        raise ValueError(f"`mask` has shape {mask_np.shape}, expected {u.shape}")
    n_fit = int(np.sum(mask_np > 0))
    if per_play * n_plays + 1 + extra > n_fit:
        what = f"{n_plays} plays" + (" and the creep" if extra else "")
        raise ValueError(
            f"{what} need {per_play * n_plays + 1 + extra} parameters but only {n_fit} samples "
            "are fitted; use fewer plays or a longer record"
        )
    u_np, y_np = np.asarray(u), np.asarray(y)
    # Finite but huge outputs overflow when residuals in the data's units are squared and summed
    # (the RMSE); say so instead of returning an infinite RMSE. The input is only normalised, so
    # its range must merely be finite.
    limit = float(np.sqrt(np.finfo(u_np.dtype).max / max(n_fit, 1)))
    if np.max(np.abs(y_np)) >= limit:
        raise ValueError(
            f"`y` has values up to {np.max(np.abs(y_np)):.3g}, out of the range the fit can square "
            f"and sum in {u_np.dtype.name} (below {limit:.3g}); rescale it, e.g. to other units"
        )
    u_lo, u_hi = float(u_np.min()), float(u_np.max())
    if not np.isfinite(u_hi - u_lo):
        raise ValueError(f"the input's range {u_lo:.3g} to {u_hi:.3g} overflows {u_np.dtype.name}; rescale `u`")
    if not u_hi > u_lo:
        raise ValueError(f"the input has zero range (constant {u_lo:.6g}): it excites no play")
    y_lo, y_hi = float(y_np.min()), float(y_np.max())
    y_half = 0.5 * (y_hi - y_lo) if y_hi > y_lo else 1.0
    mid_u, half_u, mid_y = (dtype.type(v) for v in (0.5 * (u_lo + u_hi), 0.5 * (u_hi - u_lo), 0.5 * (y_lo + y_hi)))
    half_y = dtype.type(y_half)
    # In NumPy, moved to the device once: eager JAX operations would each compile a program for
    # every record length and play count.
    s = Scales(*(_checks.to_device(v) for v in (mid_u, half_u, mid_y, half_y)))
    if thresholds0 is not None:
        r0 = np.asarray(thresholds0, dtype=np.float64)
        if r0.shape != (n_plays,) or r0[0] != 0 or np.any(np.diff(r0) <= 0):
            raise ValueError(f"`thresholds0` must be {n_plays} increasing thresholds starting at 0, got {r0}")
        thresholds0 = _checks.to_device((r0 / float(half_u)).astype(dtype))
    start = u_np[0] if initial_states is None else np.asarray(initial_states, dtype)
    x0_np = (np.broadcast_to(start, (int(n_plays),)).astype(dtype) - mid_u) / half_u
    un, yn = (u_np - mid_u) / half_u, (y_np - mid_y) / half_y
    # Records are padded to a few lengths so that nearby lengths share one compilation. Padding
    # repeats the last input, which moves no play, and its residuals are masked out.
    pad = pad_count(u.shape[0])
    if pad:
        un = np.concatenate([un, np.full(pad, un[-1], dtype)])
        yn = np.concatenate([yn, np.zeros(pad, dtype)])
        mask_np = np.concatenate([mask_np, np.zeros(pad, dtype)])
    un, yn, mask, x0 = (_checks.to_device(a) for a in (un, yn, mask_np, x0_np))
    return un, yn, mask, s, x0, thresholds0
