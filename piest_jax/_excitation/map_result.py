"""The result of a Monte Carlo PE map: one typed record of every draw's statistics."""

import dataclasses

import equinox as eqx
import numpy as np

from .families import FAMILIES
from .map_settings import MapSettings

# The per-draw quantities `piest montecarlo` writes to pe_map.json, in this order (`excited`,
# `gram_scale`, `zero_frozen` and `twin_triple` stay in the result only).
JSON_DRAWS = (
    "family",
    "rho",
    "c1",
    "c1_normalised",
    "pe",
    "min_excited",
    "redundant",
    "sharper",
    "exact",
    "exact_level",
    "margin",
    "samples_to_1pct",
    "worst_samples_to_1pct",
    "guaranteed_samples_to_1pct",
    "worst_error",
    "guaranteed_error",
    "weight_error",
    "thresholds",
)


class PEMap(eqx.Module):
    """The result of [`pe_map`][]: NumPy arrays with a leading axis of draws.

    **Fields:**

    - `settings`: the [`MapSettings`][] the map ran with; `start`, the number of its first draw;
      `devices`, the devices it was sharded over (their names).
    - `family` (draws,): each draw's input family, an index into `FAMILIES`.
    - `pe` (draws,): the PE verdict: the raw Gram level `c1_normalised` above
      `numerical_tolerance`, or, for a settled map, the rank in exact arithmetic where settled.
    - `settled` (draws,): which draws were decided in exact arithmetic; None when the map was
      not settled.
    - From [`draw_statistics`][]: `rho`, `c1`, `c1_normalised`, `gram_scale`, `excited`
      (draws, windows, n), `min_excited`, `redundant`, `zero_frozen`, `twin_triple`, `sharper`,
      `exact` (the exact condition in every window; exact where settled and below the band),
      `exact_level`, `margin`, `weight_error`, `samples_to_1pct`, `worst_samples_to_1pct`,
      `guaranteed_samples_to_1pct`, `worst_error`, `guaranteed_error`; and `thresholds`
      (draws, n).
    - `seconds`: the wall time including compilation and settling; `settle_seconds`, the
      settling's share (0 when not settled).
    """

    settings: MapSettings = eqx.field(static=True)
    start: int = eqx.field(static=True)
    devices: tuple[str, ...] = eqx.field(static=True)
    family: np.ndarray
    pe: np.ndarray
    settled: np.ndarray | None
    rho: np.ndarray
    c1: np.ndarray
    c1_normalised: np.ndarray
    gram_scale: np.ndarray
    excited: np.ndarray
    min_excited: np.ndarray
    redundant: np.ndarray
    zero_frozen: np.ndarray
    twin_triple: np.ndarray
    sharper: np.ndarray
    exact: np.ndarray
    exact_level: np.ndarray
    margin: np.ndarray
    weight_error: np.ndarray
    samples_to_1pct: np.ndarray
    worst_samples_to_1pct: np.ndarray
    guaranteed_samples_to_1pct: np.ndarray
    worst_error: np.ndarray
    guaranteed_error: np.ndarray
    thresholds: np.ndarray
    seconds: float = eqx.field(static=True)
    settle_seconds: float = eqx.field(static=True, default=0.0)

    @property
    def n_draws(self) -> int:
        """The number of draws."""
        return int(np.shape(self.rho)[0])

    def arrays(self) -> dict:
        """Every per-draw array by name (`settled` only for a settled map): for `np.savez`, a
        DataFrame, or comparing two maps.

        **Returns:** a dict of NumPy arrays with a leading axis of draws.
        """
        names = [f.name for f in dataclasses.fields(self) if not f.metadata.get("static", False)]
        return {k: np.asarray(getattr(self, k)) for k in names if getattr(self, k) is not None}

    def summary(self) -> dict:
        """The counts the map is judged by ([`summarise`][]).

        **Returns:** a JSON-ready dict.
        """
        from .map_report import summarise

        return summarise(self)

    def to_json(self) -> dict:
        """What `piest montecarlo` writes to pe_map.json (less the seed, which the key hides).

        **Returns:** a JSON-ready dict: `n_inputs`, `start`, `seconds`, `devices`, `settings`,
        `family_names`, the [`summary`][piest_jax.PEMap.summary]'s keys, and `draws`: the
        per-draw arrays named in `JSON_DRAWS` (plus `settled` for a settled map).
        """
        draws = {k: getattr(self, k) for k in JSON_DRAWS}
        if self.settled is not None:
            draws["settled"] = self.settled
        return {
            "n_inputs": self.n_draws,
            "start": self.start,
            "seconds": self.seconds,
            "devices": list(self.devices),
            "settings": self.settings._asdict(),
            "family_names": list(FAMILIES),
            **self.summary(),
            "draws": draws,
        }
