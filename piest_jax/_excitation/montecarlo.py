"""The Monte Carlo PE map engine: a batch of PRNG keys, chunked, sharded over devices.

One draw is one PRNG key: it fixes an input family and its parameters, a threshold set, initial
play states and true weights (see `families/`); `draw_statistics` (`_draw_metrics.py`) turns
it into the map's quantities. The batch runs as one jitted computation per chunk of keys, with
the key axis sharded over every JAX device through a one-axis `Mesh` and `NamedSharding`.
After `jax.distributed.initialize` the devices are those of every process (host): each process
then runs the same loop over chunks, hands the keys of its own devices to the computation, and
gets every draw's statistics back.
"""

import functools
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from .. import _checks
from .._progress import progress
from .draw import draw_case
from .draw_metrics import draw_statistics
from .map_result import PEMap
from .map_settings import MapSettings, numerical_tolerance
from .settle import settle_draws

_DRAWS_PER_STEP = 1


def draw_keys(key, start: int, count: int):
    """Keys of draws start, ..., start + count − 1: draw i is fold_in(key, i), whatever the batch.

    **Arguments:** `key`, a PRNG key; `start`, the first draw number; `count`, how many.

    **Returns:** (count,) keys (new-style, whichever kind `key` is).
    """
    key = _checks.prng_key(key)
    return jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.arange(start, start + count))


def draw_family(index, settings: MapSettings):
    """The family (index into `FAMILIES`) of draw number `index`: the families take turns.

    **Arguments:** `index`, draw numbers (an int or an array); `settings` of the map.

    **Returns:** family indices, shaped like `index`.
    """
    return np.asarray(settings.families)[np.asarray(index) % len(settings.families)]


def _cases(keys, settings: MapSettings):
    """(u, r, x0, w) of a batch of keys whose first draw number is a multiple of the family count."""
    s = settings
    nf = len(s.families)
    t = s.times()
    by_family = keys.reshape(-1, nf)
    cases = [jax.vmap(lambda k, f=f: draw_case(k, f, t, s.n_plays))(by_family[:, j]) for j, f in enumerate(s.families)]
    # Interleave back so row i of the result is draw i of the batch.
    return tuple(jnp.stack(parts, axis=1).reshape((keys.shape[0],) + parts[0].shape[1:]) for parts in zip(*cases))


def _local_batch(keys, settings: MapSettings, loop: bool = True, inputs: bool = False) -> dict:
    """Statistics of a batch of keys whose first draw number is a multiple of the family count.

    `loop`: one draw at a time (for CPUs), else one `vmap` over the batch (for accelerators).
    `inputs`: also return the drawn `u` and `x0` (for settling; `thresholds` always come back).
    """
    s = settings
    u, r, x0, w = _cases(keys, s)
    stats = functools.partial(draw_statistics, settings=s)
    if loop:
        # One draw at a time rather than one vmap over the batch: a draw's play outputs (T, n)
        # then stay in cache through every windowed statistic instead of streaming the whole
        # batch's from memory once per statistic (2 to 3 times less work on a CPU), and each
        # eigensolver call gets one matrix, which the CPU solver runs inline (see
        # `draw_statistics`). An accelerator wants the whole batch at once instead.
        out = lax.map(lambda case: stats(*case), (u, r, x0, w), batch_size=_DRAWS_PER_STEP)
    else:
        out = jax.vmap(stats)(u, r, x0, w)
    out["thresholds"] = r
    if inputs:
        out |= dict(u=u, x0=x0)
    return out


def mesh_sharding(devices) -> NamedSharding:
    """The sharding the engine puts the keys under: one mesh axis, "batch", over `devices`.

    **Arguments:** `devices`, a sequence of JAX devices (e.g. `jax.devices()`).

    **Returns:** a `NamedSharding` over a one-axis `Mesh`, splitting the leading axis.
    """
    return NamedSharding(Mesh(np.asarray(tuple(devices)), ("batch",)), PartitionSpec("batch"))


def _global_keys(keys, sharding: NamedSharding):
    """`keys`, the same on every process, as one array over devices of several processes.

    `device_put` places data on this process's devices only: here each process gives the slices
    that its own devices hold (typed keys as they are; JAX 0.6 and later take them).
    """
    return jax.make_array_from_callback(keys.shape, sharding, lambda index: keys[index])


@functools.lru_cache(maxsize=16)
def _engine(settings: MapSettings, devices: tuple, inputs: bool = False):
    sharding = mesh_sharding(devices)
    # shard_map keeps every device on its own slice of keys, also through the compiled play
    # kernel, which the automatic partitioner could not split.
    loop = all(d.platform == "cpu" for d in devices)
    fn = jax.shard_map(
        functools.partial(_local_batch, settings=settings, loop=loop, inputs=inputs),
        mesh=sharding.mesh,
        in_specs=sharding.spec,
        out_specs=sharding.spec,
    )
    return jax.jit(fn, in_shardings=sharding, out_shardings=sharding), sharding


def pe_map(
    key,
    n_draws: int,
    settings: MapSettings,
    *,
    chunk: int = 1000,
    start: int = 0,
    devices=None,
    settle: bool = False,
    quiet: bool = False,
) -> PEMap:
    """Run the Monte Carlo map: `n_draws` draws, `chunk` at a time, sharded over `devices`.

    **Arguments:**

    - `key`: a PRNG key, new-style or legacy (`jax.random.PRNGKey`, the same numbers); draw i
      uses `fold_in(key, i)` and family `draw_family(i)`, so the draws do not depend on `chunk`
      or on the number of devices, and the statistics computed from them only up to rounding
      (a different batch shape can change the order of floating-point sums, by about 1e-16
      relative in float64).
    - `n_draws`: number of draws, >= 1.
    - `settings`: from [`make_settings`][].
    - `chunk`: draws per jitted call (bounds memory); rounded up to a multiple of the device count
      times the number of families.
    - `start`: the number of the first draw, a multiple of the number of families: a long map
      can be split over runs or hosts (draws start, ..., start + n_draws − 1).
    - `devices`: the devices to shard over (default all of `jax.devices()`). After
      `jax.distributed.initialize` these are every process's devices: every process must then
      call `pe_map` with the same arguments and hold at least one of `devices`, and each gets
      the whole map back, the one a single process with as many devices computes.
    - `settle`: decide in exact arithmetic, on the host after each chunk, every draw whose
      verdict floating point cannot decide ([`needs_settling`][piest_jax.needs_settling]: its
      event level below [`settle_band`][piest_jax.settle_band], or its two float verdicts
      disagreeing), from the very input floats the chunk drew ([`exact_draw_pe`][piest_jax.exact_draw_pe]);
      about 25 ms a draw at T = 2000, and most draws that are not PE need it.
    - `quiet`: no progress bar.

    **Returns:** a [`PEMap`][]: every draw's statistics (see [`draw_statistics`][]), its `pe`
    verdict (the raw Gram level above `numerical_tolerance`, or with `settle` the rank in exact
    arithmetic where settled; `exact` is then also exact where the event level is below the
    band, and `settled` says which draws were settled), and the wall time.
    """
    key = _checks.prng_key(key)
    for name, v in (("n_draws", n_draws), ("chunk", chunk)):
        if not _checks.is_whole(v) or v < 1:
            raise ValueError(f"`{name}` must be a positive whole number, got {v!r}")
    n_draws, chunk = int(n_draws), int(chunk)
    if not isinstance(settings, MapSettings):
        raise ValueError("`settings` must come from make_settings(...)")
    nf = len(settings.families)
    if isinstance(start, bool) or not isinstance(start, int | np.integer) or start % nf or start < 0:
        raise ValueError(f"`start` must be a non-negative multiple of {nf} (the families), got {start!r}")
    devices = tuple(jax.devices() if devices is None else devices)
    # Devices of other processes take no device_put and give no device_get: see _global_keys.
    here = jax.process_index()
    spans_processes = any(d.process_index != here for d in devices)
    if spans_processes and not any(d.process_index == here for d in devices):
        raise ValueError(
            f"`devices` holds none of this process's devices (process {here}): every process of a "
            "distributed run must take part in the map with at least one of its devices"
        )
    unit = len(devices) * nf
    chunk = -(-min(chunk, n_draws) // unit) * unit
    fn, sharding = _engine(settings, devices, settle)
    start_time = time.perf_counter()
    parts, settle_seconds = [], 0.0
    offsets = range(0, n_draws, chunk)
    for offset in progress(offsets, total=len(offsets), desc="PE map", quiet=quiet):
        # The last chunk is padded to the full size so every call reuses one compiled program.
        if spans_processes:
            keys = _global_keys(draw_keys(key, start + offset, chunk), sharding)
            out = multihost_utils.process_allgather(fn(keys), tiled=True)
        else:
            keys = jax.device_put(draw_keys(key, start + offset, chunk), sharding)
            out = jax.device_get(fn(keys))
        out = {k: v[: n_draws - offset] for k, v in out.items()}
        if settle:
            t0 = time.perf_counter()
            out = settle_draws(out, settings)
            settle_seconds += time.perf_counter() - t0
        parts.append(out)
    result = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    if not settle:
        result["pe"] = result["c1_normalised"] > numerical_tolerance(settings.dtype)
    return PEMap(
        settings=settings,
        start=int(start),
        devices=tuple(str(d) for d in devices),
        family=draw_family(start + np.arange(n_draws), settings),
        settled=result.pop("settled", None),
        **result,
        seconds=time.perf_counter() - start_time,
        settle_seconds=settle_seconds,
    )
