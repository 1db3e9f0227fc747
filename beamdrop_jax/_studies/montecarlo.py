"""Random drops: how likely is the board to exceed its limit when the product falls at random?

Samples are drawn up front from the key, one stream per randomised field, so the same key gives the same drops
whatever the chunk size or the number of devices. Chunks of drops are evaluated by one compiled, vmapped function,
sharded over every local device along a 1-D mesh (`jax.sharding.NamedSharding`). On several hosts, call
`jax.distributed.initialize()` first: `jax.devices()` then spans the hosts and the same code path shards over all
of them.
"""

import collections
import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from jaxtyping import Array, Bool, Float, Int
from tqdm import tqdm

from .._common.checks import Flag, as_int, float_dtype, is_concrete, is_pulse
from .._scene.containers import Scene, check_scene
from .._response.numerics import Numerics
from .._response.objectives import _scene_peaks
from .._impact.kinematics import housing_impact
from .._response.landing_path import FIRST_LANDING_STEPS, compliant_weight
from .._response.simulate import drop_motion
from .._response.superposition import superposes, superposition_table, table_numerics, table_peaks
from .._response.surface import forget_modes
from .._common.compile import filter_jit
from .._common.memo import keep, tree_digest
from .._board.base import natural_frequencies
from .._common.report import summary_text
from .distribution import _FIELDS, _PLANE_FIELDS, DropDistribution, sample_axes
from .landings import solve_landings

_AHEAD = 2


def wilson_interval(k, n, confidence=0.95) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion k/n (k of n drops exceed a limit) at `confidence`; with
    n = 0, (0, 1): no information."""
    if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (k, n)) or not 0 <= k <= n:
        raise ValueError(f"k = {k!r}, n = {n!r}; valid: ints with 0 <= k <= n")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence = {confidence!r}; valid: (0, 1), e.g. 0.95")
    if n == 0:
        return (0.0, 1.0)
    from statistics import NormalDist

    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    # At k = 0 (k = n) the bound is exactly 0 (1); the formula leaves a rounding residue such as 1e-19.
    return (0.0 if k == 0 else max(0.0, centre - half), 1.0 if k == n else min(1.0, centre + half))


class MonteCarloResult(eqx.Module):
    """Random drops and their peaks.

    - `samples`: a `Scene` whose varied fields have a leading axis n (re-simulate drop i with `result.scene(i)`).
    - `peak_stress` (Pa), `peak_strain` (-), `peak_deflection` (m): shape (n,), NaN for invalid drops.
    - `valid`: (n,) bool; `flags`: (n,) `Flag` masks. Invalid drops (e.g. flat landings with spin, separating
      contacts) are counted in `n_invalid` and left out of every summary.
    - `landing_weight`: (n,) the compliant landing's share of each drop's supports' motion (`Contact.model`;
      0 where the first corner strikes alone: the rigid law's fast path).
    """

    samples: Scene
    peak_stress: Float[Array, " n"]
    peak_strain: Float[Array, " n"]
    peak_deflection: Float[Array, " n"]
    flags: Int[Array, " n"]
    valid: Bool[Array, " n"]
    landing_weight: Float[Array, " n"] | None = None

    @property
    def n_compliant(self) -> int:
        """Drops that took the compliant landing (near-flat landings: `landing_weight` > 0)."""
        return 0 if self.landing_weight is None else int(np.sum(np.asarray(self.landing_weight) > 0))

    @property
    def n(self) -> int:
        return int(self.valid.shape[0])

    @property
    def n_invalid(self) -> int:
        return int(self.n - np.sum(np.asarray(self.valid)))

    def scene(self, i: int) -> Scene:
        """Drop i as a single scene."""
        n = self.n
        return jax.tree_util.tree_map(lambda v: v[i] if (jnp.ndim(v) and jnp.shape(v)[0] == n) else v,
                                      self.samples, is_leaf=lambda v: False)

    def _values(self, quantity):
        if quantity not in ("stress", "strain", "deflection"):
            raise ValueError(f"quantity = {quantity!r}; valid: stress, strain, deflection")
        values = np.asarray(getattr(self, f"peak_{quantity}"))
        return values[np.asarray(self.valid)]

    def summary(self, quantity: str = "stress", quantiles=(0.5, 0.9, 0.99, 0.999)) -> dict:
        """Mean, standard deviation, quantiles and maximum of a peak (SI units) over the valid drops; NaN where
        there are too few valid drops."""
        v = self._values(quantity)
        nan = float("nan")
        out = {"n": int(v.size), "n_invalid": self.n_invalid, "mean": float(v.mean()) if v.size else nan,
               "std": float(v.std(ddof=1)) if v.size > 1 else nan}
        out.update({f"q{q:g}": float(np.quantile(v, q)) if v.size else nan for q in quantiles})
        out["max"] = float(v.max()) if v.size else nan
        return out

    def exceedance(self, limit: float, quantity: str = "stress", confidence: float = 0.95):
        """P(peak > limit) over the valid drops with its Wilson interval: (p, (low, high), count). `limit` in SI
        units (Pa, strain as a fraction, m); p is NaN with the interval (0, 1) when no drop is valid."""
        limit = float(limit)
        if not (np.isfinite(limit) and limit >= 0):
            raise ValueError(f"limit = {limit}: valid a finite {quantity} >= 0 in SI units")
        if quantity == "strain" and limit >= 0.2:
            raise ValueError(f"limit = {limit:g}: strain limits are fractions (2000 microstrain is 2e-3)")
        v = self._values(quantity)
        k = int(np.sum(v > limit))
        return (k / v.size if v.size else float("nan")), wilson_interval(k, v.size, confidence), k

    def invalid_reasons(self) -> dict:
        """How many drops each `Flag` left out, by flag name."""
        flags = np.asarray(self.flags).ravel()
        return {f.name: int(np.sum((flags & f.value) != 0)) for f in Flag if f.value and np.any(flags & f.value)}

    def report(self, limit: float | None = None, quantity: str = "strain") -> dict:
        """Statistics of stress and strain in engineering units (MPa, microstrain), the invalid drops by reason,
        and with `limit` (SI) the exceedance probability of `quantity` with its 95 % Wilson interval."""
        stress, strain = self.summary("stress"), self.summary("strain")
        out = {"drops": self.n, "drops_outside_the_model": self.n_invalid,
               "drops_with_a_compliant_landing": self.n_compliant}
        if self.n_invalid:
            out["outside_the_model_by_reason"] = self.invalid_reasons()
        out |= {
            "peak_stress_mean_MPa": stress["mean"] / 1e6, "peak_stress_std_MPa": stress["std"] / 1e6,
            "peak_stress_median_MPa": stress["q0.5"] / 1e6, "peak_stress_q99_MPa": stress["q0.99"] / 1e6,
            "peak_stress_max_MPa": stress["max"] / 1e6,
            "peak_strain_median_microstrain": strain["q0.5"] * 1e6,
            "peak_strain_q99_microstrain": strain["q0.99"] * 1e6, "peak_strain_max_microstrain": strain["max"] * 1e6,
        }
        if limit is not None:
            unit, scale = {"stress": ("MPa", 1e-6), "strain": ("microstrain", 1e6), "deflection": ("mm", 1e3)}[quantity]
            p, (lo, hi), k = self.exceedance(limit, quantity)
            out |= {f"limit_{unit}": limit * scale, "drops_over_limit": k, "probability_over_limit": p,
                    "probability_95pct_interval": [lo, hi]}
        return out

    def __repr__(self) -> str:
        return summary_text(self.report(), "MonteCarloResult")


def montecarlo_numerics(scene: Scene, distribution: "DropDistribution | None" = None, max_impacts: int = 1
                        ) -> Numerics:
    """Lean numerics for many drops, chosen from the scene: modes up to f_k tau >= 1 for the shortest pulse the
    distribution can draw (at least 3; 16 for an ideal impulse), a coarse grid (3 points per period of the top
    mode, 2 per mode along the board), one candidate peak and two Newton steps from the grid's parabolic vertex.
    Measured against 32 modes (`beamdrop bench`, tests/test_montecarlo.py): 0.66 % worst-case error on the default
    scene's random drops (4 modes); at most 0.91 % on a 0.1 ms pulse (9 modes), a 3 % damped board and drops with
    random height, spin, drift, friction and restitution. 2 points per period were 15 % faster but missed the
    peak by up to 1.8 % on the short pulse. A board with a clamp or a free end converges more slowly at its ends:
    modes up to f_k tau >= 2 and two candidates (within 1e-7 of `table_numerics` on the default drops; with the
    pinned settings up to 2.6 % low). Plates take the clamped beam's settings: on the JESD22 board's random drops
    within 0.25 % of a 16-points-per-period search.

    Clattering (`max_impacts` > 1): three modes more (the impacts' superposed vibrations carry more of the higher
    modes), a grid of 2 points per period of the top mode and 3 per mode along the board, and three candidates
    refined: each impact's window nominates three, ranked by their parabolic interpolation. On 1024 random default
    drops with 3 impacts: within 0.27 % of 32 modes (the single-impact mode count plus one: 1.5 %)."""

    tau = float(scene.contact.duration)
    pinned = getattr(scene.board, "ends", None) == "pinned"  # plates converge as slowly as clamped beams
    spec = None if distribution is None else distribution.duration
    if spec is not None:
        tau = spec[1] if spec[0] == "uniform" else spec[1] * math.exp(-3 * spec[2])
    if not is_pulse(tau):
        n = 16
    else:
        f_tau = np.asarray(natural_frequencies(scene.board, 64)) / (2 * math.pi) * tau
        n = int(min(max(np.sum(f_tau < (1.0 if pinned else 2.0)) + 1, 3), 64))
    if max_impacts > 1:
        return Numerics(n_modes=min(n + 3, 64), candidates=3, newton_steps=2, points_per_period=2, x_points_per_mode=3,
                        max_impacts=max_impacts)
    return Numerics(n_modes=n, candidates=1 if pinned else 2, newton_steps=2, points_per_period=3,
                    x_points_per_mode=2)


def inner_batch(numerics: Numerics, batch: int, n_devices: int = 1, plate: bool = False) -> int:
    """Drops vmapped at once inside a compiled chunk, a multiple of the device count: a power of two near 2M grid
    values in all for beams (one (nx, nt) grid per impact; measured on 2 cores: a single impact's drops 3.1 ->
    2.4 us and a clattering drop 36 -> 31 us against 128k values, which kept the grids in cache but paid the
    loop's per-step cost more often), 128k for a plate's far larger grids."""
    nx, nt = numerics.grid_shape()
    values = (131072 if plate else 1 << 21) // (nx * nt * numerics.max_impacts)
    inner = 2 ** max(3, int(math.log2(max(1, values))))
    inner = min(inner, batch)
    return -(-inner // n_devices) * n_devices


def evaluate_batch(samples, axes, numerics, grid_deflection=False, inner=None):
    """Peaks (stress, strain, deflection, flags) of a batch of drops, `inner` drops vmapped at a time in a loop
    (`inner` must divide the batch; None: all at once). Drop i goes to lane i // steps of step i % steps, so a
    batch sharded in contiguous blocks stays sharded along the lanes.

    Beams compile with YNNPACK's product fusions only (`_compile.compiler_options`; a clattering drop 54 -> 36 us);
    plates with the package's usual options, under which their searches were validated (the other rounding moved
    a plate's Monte-Carlo peaks by up to 4e-6 from each drop's own search)."""
    compiled = _evaluate_plates if samples.board.SURFACE else _evaluate_beams  # validated options per domain
    return compiled(samples, axes, numerics, grid_deflection, inner)


def _batch_peaks(samples, axes, numerics, grid_deflection, inner):
    def one(scene, motion_and_flags):
        motion, impact_flags = motion_and_flags
        # The pulse's duration from the scene: shared by the drops (not batched) unless the distribution varies it,
        # so that the board's response factors are computed once for all drops.
        motion = eqx.tree_at(lambda m: m.duration, motion, scene.contact.duration)
        quantities = ("stress", "strain", "deflection")
        (stress, strain, deflection), flags = _scene_peaks(scene, numerics, quantities, grid_deflection,
                                                           (motion, impact_flags))
        return stress, strain, deflection, flags

    def motion(scene):
        motion, _, _, flags = drop_motion(scene, numerics)
        return motion, flags

    # The impact sequences of the whole batch at once: their searches for the next impact are loops, which cost
    # per iteration, not per drop (clattering 8 -> 2.4 us per drop with `inner` drops at a time).
    motions = jax.vmap(motion, in_axes=(axes,))(samples)
    vmapped = jax.vmap(one, in_axes=(axes, 0))
    leaves, treedef = jax.tree_util.tree_flatten(samples)
    n = int(next(v.shape[0] for v, a in zip(leaves, treedef.flatten_up_to(axes)) if a is not None))
    if inner is None or inner >= n:
        return vmapped(samples, motions)
    if n % inner:
        raise ValueError(f"inner = {inner} must divide the batch ({n})")
    steps = n // inner
    batched = [a is not None for a in treedef.flatten_up_to(axes)]
    motion_leaves, motion_treedef = jax.tree_util.tree_flatten(motions)

    def step(parts):
        scene_parts, motion_parts = parts
        it = iter(scene_parts)
        return vmapped(treedef.unflatten([next(it) if b else v for v, b in zip(leaves, batched)]),
                       motion_treedef.unflatten(motion_parts))

    fold = lambda v: v.reshape((inner, steps) + v.shape[1:]).swapaxes(0, 1)  # noqa: E731
    out = jax.lax.map(step, ([fold(v) for v, b in zip(leaves, batched) if b], [fold(v) for v in motion_leaves]))
    return jax.tree_util.tree_map(lambda v: v.swapaxes(0, 1).reshape((n,) + v.shape[2:]), out)


_evaluate_beams = filter_jit(dot_fusions_only=True)(_batch_peaks)
_evaluate_plates = filter_jit(_batch_peaks)


def montecarlo(
    scene: Scene,
    n: int,
    key,
    distribution: DropDistribution | None = None,
    numerics: Numerics | None = None,
    batch_size: int | None = None,
    devices=None,
    progress: bool = True,
    refine_deflection: bool = False,
    superpose: bool | None = None,
    max_landings: int = 4000,
) -> MonteCarloResult:
    """Simulate n random drops of `scene` with fields drawn from `distribution`.

    Two ways to the peaks:
    - **superposed** (`superpose=True`; the default wherever it applies: one impact, the closed form): the
      board's response is linear in its two support jumps, so one `SuperpositionTable` per board holds the peak
      search at 256 jump directions and each drop costs its impact plus a few multiply-adds (10-15 million
      drops/s on 2 cores, table build included). Peaks are at most 6.4e-5 (stress) and 2.4e-4 (deflection) below
      the peak of the modal series, never above it. When `distribution.duration` varies, the table spans the
      sampled durations (17 nodes, 128 directions; 0.1-0.25 s to build) and a drop interpolates between them: at
      most 4.6e-4 (stress) and 1.7e-3 (deflection) below a dense per-drop search, and 3.5e-5 above it, on
      random drops with durations uniform on [0.2, 1] ms; up to 3.4e-3 on a clamped board, whose peak can move
      to another clamp or time between two table durations (tests/test_montecarlo.py). A plate's table
      (`PlateTable`) holds one contact duration: the JESD22 board's peaks within 4.9e-4 of a dense per-drop
      search, about 1.2 million drops/s on 2 cores (`beamdrop bench`). A box tilted or moving out of the plane
      rolls a plate's supports across its width: its table spans the sphere of jump directions (dvA, dvB, dvR;
      `superposition_table(..., rolls=True)`, 33 x 33 directions, a quarter of them searched on a plate that is
      its own mirror image in x and y), within 1e-3 of a dense search (the deflection 3e-3). Default numerics:
      `table_numerics(scene, durations)`. The last four boards' tables stay in memory (`forget_tables`), so a
      later call on the same board builds none: the JESD22 plate's 2^20 drops then take 0.17 s instead of 1.26 s.
    - **direct** (`superpose=False`; the only way when `Numerics.max_impacts` > 1, for the diffrax method, when
      sampled durations reach 0, or vary on a plate): each drop runs its own peak search, exactly as `simulate(drop, numerics)`
      does. Default numerics: `montecarlo_numerics(scene, distribution)`.

    **Near-flat landings** (`Contact.model` "auto", the default): the drops whose strikes overlap
    (`compliant_weight` > 0; about 6 % of uniform orientations) take the compliant landing's path, `simulate`'s
    (`LANDING_SECONDS` a drop: 0.005 s on a beam, 0.015 s on a plate), and replace the fast path's peaks
    (`MonteCarloResult.landing_weight` says which); "compliant" takes it for every drop, "rigid" for none. Where
    only the orientation of a plane section varies and the band's drops outnumber its nodes, an
    `orientation_table` (0.05 deg apart, within 5e-3 of each drop's solve; the last four scenes' stay in memory)
    gives them. Over `max_landings` solves is refused first.

    **Arguments:**
    - `key`: a `jax.random.PRNGKey`; the same key gives the same drops and results for any `batch_size` and
      device count.
    - `batch_size`: drops per compiled chunk (one transfer, one progress step); default min(n, 65536) superposed,
      min(n, 16384) direct, rounded up to a multiple of the drops vmapped at a time (`inner_batch`).
    - `devices`: devices to shard each chunk over (default all local devices).
    - `refine_deflection` (direct): refine the deflection peak too, 28 % slower (default: the grid's maximum, a
      lower bound that undershoots by the grid's resolution: by 2.3 % at the 1st percentile and at most 4.8 % over
      10,000 drops of five scenes, default numerics; stress and strain, and superposed deflections, are refined).
    """
    n = as_int(n, "n", 1)
    as_int(max_landings, "max_landings", 0)
    distribution, box_only = _checked_distribution(scene, distribution)
    samples = distribution.sample(scene, n, key)
    durations = None  # the table's span of contact durations, when they vary
    cannot = superposes(Numerics() if numerics is None else numerics, scene.board)
    if distribution.duration is not None and cannot is None:
        tau = np.asarray(samples.contact.duration)
        durations = (float(tau.min()), float(tau.max()))
        if not durations[0] > 0:
            cannot = (f"the sampled contact durations reach {durations[0]:g} s (a table spans durations > 0; an "
                      "ideal impulse, 0, is a table of its own: fix Contact.duration = 0)")
        elif not durations[1] > durations[0]:
            scene, durations = scene.replace(**{"contact.duration": durations[0]}), None
        else:
            cannot = superposes(Numerics() if numerics is None else numerics, scene.board, durations)
    # A box tilted or moving out of the plane rolls a plate's supports across its width: a table over the sphere.
    rolls = bool(scene.board.SURFACE and scene.housing.is_box and (
        box_only or np.any(np.asarray(scene.drop.tilt)) or not np.all(scene.drop.in_plane())))
    if cannot is None and rolls and durations is not None:
        cannot = ("a plate's table over the sphere of jump directions (a box's drops out of the plane) holds one "
                  "contact duration")
    if superpose and cannot:
        raise ValueError(f"montecarlo(superpose=True) needs one pulse for every drop, but {cannot}")
    superpose = cannot is None if superpose is None else bool(superpose)
    from_rest = _from_rest(scene, samples)
    devices = jax.local_devices() if devices is None else list(devices)
    n_dev = len(devices)
    if batch_size is not None and not (isinstance(batch_size, (int, np.integer)) and batch_size >= 1):
        raise ValueError(f"batch_size = {batch_size!r}; valid: an int >= 1")
    if superpose:
        numerics = table_numerics(scene, durations) if numerics is None else numerics
        table = _kept_superposition(scene, numerics, durations, rolls)
        batch = min(n, 65536) if batch_size is None else int(batch_size)
        inner = n_dev
        evaluate = lambda chunk, axes: table_peaks(table, chunk, axes, from_rest)  # noqa: E731
    else:
        numerics = montecarlo_numerics(scene, distribution) if numerics is None else numerics
        numerics = dataclasses.replace(numerics, from_rest=numerics.from_rest or from_rest)
        # Grids live only `inner_batch` drops at a time, so a chunk is memory-light: large chunks amortise the
        # per-chunk transfer and dispatch.
        batch = min(n, 16384) if batch_size is None else int(batch_size)
        inner = inner_batch(numerics.for_board(scene.board), batch, n_dev, plate=scene.board.SURFACE)
        evaluate = lambda chunk, axes: evaluate_batch(chunk, axes, numerics, not refine_deflection, inner)  # noqa: E731
    batch = -(-batch // inner) * inner
    axes = sample_axes(samples, scene)
    mesh = Mesh(np.asarray(devices), ("drops",))
    sharded = NamedSharding(mesh, PartitionSpec("drops"))
    replicated = NamedSharding(mesh, PartitionSpec())
    leaves, treedef = jax.tree_util.tree_flatten(samples)
    batched = [a is not None for a in treedef.flatten_up_to(axes)]
    # Fixed fields go to the devices once; varied ones are sliced per chunk from host copies.
    leaves = [np.asarray(v) if b else jax.device_put(v, replicated) for v, b in zip(leaves, batched)]

    def chunk_of(v, start, stop):
        part = v[start:stop]
        if stop - start < batch:
            # The last chunk is padded with its own first drop so every chunk has one compiled shape.
            part = np.concatenate([part, np.broadcast_to(part[:1], (batch - (stop - start),) + part.shape[1:])])
        return jax.device_put(part, sharded)

    # Chunks are dispatched ahead (JAX runs them asynchronously) so that slicing, transfers and dispatch of the
    # next chunks overlap the computation of earlier ones; at most `_AHEAD` chunks are in flight.
    outputs = [np.empty(n, dtype) for dtype in (float_dtype(),) * 3 + (np.int32,)]
    starts = range(0, n, batch)
    pending = collections.deque()

    def collect():
        start, result = pending.popleft()
        stop = min(start + batch, n)
        for out, v in zip(outputs, result):
            out[start:stop] = np.asarray(v)[: stop - start]
        bar.update(1)

    with tqdm(total=len(starts), desc="montecarlo", disable=not progress, leave=False) as bar:
        for start in starts:
            stop = min(start + batch, n)
            chunk = treedef.unflatten([chunk_of(v, start, stop) if b else v for v, b in zip(leaves, batched)])
            pending.append((start, evaluate(chunk, axes)))
            if len(pending) > _AHEAD:
                collect()
        while pending:
            collect()
    weight = _landings(scene, samples, axes, outputs, numerics, progress, max_landings)
    # `device_put`, not `jnp.asarray`: 1.2 against 5.3 ms for an 8 MB array.
    stress, strain, deflection, flags, valid = jax.device_put(outputs + [outputs[3] == Flag.OK])
    return MonteCarloResult(samples, stress, strain, deflection, flags, valid, jax.device_put(weight))


def _checked_distribution(scene: Scene, distribution) -> tuple["DropDistribution", list[str]]:
    """`montecarlo`'s distribution (default `DropDistribution()`), checked against the scene (which is checked), and
    the fields it varies that only a box has."""
    distribution = DropDistribution() if distribution is None else distribution
    if not isinstance(distribution, DropDistribution):
        raise ValueError(f"distribution must be a DropDistribution, got {type(distribution).__name__}")
    if not distribution.varied():
        raise ValueError("DropDistribution varies no field: every drop would be the same (use simulate for one drop)")
    check_scene(scene)
    box_only = [name for name in list(_FIELDS)[_PLANE_FIELDS:] if getattr(distribution, name) is not None]
    if box_only and not scene.housing.is_box:
        raise ValueError(f"DropDistribution.{box_only[0]} varies a box housing's drop out of the plane: give "
                         f"Housing.depth (m), or leave {', '.join(box_only)} out for the plane section")
    return distribution, box_only


def _from_rest(scene: Scene, samples: Scene) -> bool:
    """Whether every sampled drop of a box starts from rest: its 3D law in closed form (`Numerics.from_rest`)."""
    d = samples.drop
    return bool(scene.housing.is_box and not any(np.any(np.asarray(v)) for v in
                                                 (d.spin, d.horizontal_speed, d.side_speed, d.spin_x, d.spin_y)))


LANDING_SECONDS = (0.005, 0.015)
"""Measured cost of a near-flat drop on the compliant path, s, on a beam and on a plate (2 cores, after compiling:
5.3-5.5 ms over 110 drops of the default scene, heights uniform on [0.5, 1.5] m; 8.9-15 ms per node of the
`jesd22-board` plate's orientation table on `Contact.model` "auto", its modes solved once for all of them)."""


def _minutes(seconds: float) -> str:
    return f"{seconds:.2g} s" if seconds < 90 else f"{seconds / 60:.0f} min"


def _landings(scene, samples, axes, outputs, numerics, progress, max_landings):
    """The drops whose strikes overlap (`compliant_weight` > 0 under `Contact.model` "auto", every drop under
    "compliant"): their peaks on the compliant landing's path (`simulate`'s, default numerics), written over the
    fast path's in `outputs`, each solved, or, where only the orientation varies and the band's drops lie between
    fewer nodes of an `orientation_table` than they are, read from that table. Returns the weights (n,)."""
    n = outputs[0].shape[0]
    if scene.contact.model == "rigid" or numerics.max_impacts > 1:
        return np.zeros(n)
    orientation_only = _only_orientation_varies(scene, axes)
    key = tree_digest(scene) if orientation_only else None
    orientation = np.asarray(samples.drop.orientation)
    weight = (_orientation_weights(scene, key, orientation) if orientation_only
              else np.asarray(_weights(samples, axes, _from_rest(scene, samples))))
    band = np.flatnonzero(weight > 0)
    if band.size == 0:
        return weight
    nodes = _nodes_around(orientation[band]) if orientation_only else None
    # The table where it needs fewer nodes than the band has drops (a choice by the drops alone, so that a run's
    # answer does not depend on what earlier runs kept); kept nodes are not solved again.
    use_table = nodes is not None and nodes.size < band.size
    solves = (np.unique(_representatives(scene, _missing_nodes(key, nodes))).size if use_table else band.size)
    if solves > max_landings:
        seconds = LANDING_SECONDS[bool(scene.board.SURFACE)]
        raise ValueError(
            f"{band.size} of the {n} drops ({100 * band.size / n:.2g} %) land nearly flat, where corners strike "
            f"together; that takes {solves} solves on the compliant landing's path, about {seconds:g} s "
            f"each on 2 cores (about {_minutes(solves * seconds)} here), more than max_landings = "
            f"{max_landings} allows. Valid: fewer drops, max_landings >= {solves} (--max-landings) to pay for "
            'them, or Contact(model="rigid") (--contact-model rigid: the first strike only, fast, but it misses '
            "the near-flat drops' peaks)")
    if use_table:
        values = _kept_table(scene, key, nodes, progress).lookup(orientation[band])
    else:
        values = solve_landings(samples, axes, band, progress)
    for out, v in zip(outputs, values):
        out[band] = v
    return weight


ORIENTATION_STEP = math.radians(0.05)
"""Node spacing of `orientation_table`, rad: the near-flat band's peaks move by at most 3.5 % between neighbours
0.05 deg apart on the default scene."""


def _only_orientation_varies(scene: Scene, axes) -> bool:
    """Whether the drops of a plane section differ in their orientation alone (the band's table applies)."""
    return (not scene.housing.is_box and len(jax.tree_util.tree_leaves(axes)) == 1
            and axes.drop.orientation == 0)


def _orientation_nodes(scene: Scene) -> np.ndarray:
    """Indices k of the orientations k `ORIENTATION_STEP` on [0, 2 pi) whose drop, or a neighbour's, lands nearly
    flat (`compliant_weight` > 0): what `orientation_table` solves."""
    wanted = _weights_at(scene, jnp.arange(_node_count()) * ORIENTATION_STEP) > 0
    wanted |= np.roll(wanted, 1) | np.roll(wanted, -1)
    return np.flatnonzero(wanted)


_WEIGHT_CHUNK = 1 << 14  # drops per call of the weights' program in `_orientation_weights` (one compiled shape)
_GRID_WEIGHTS: "collections.OrderedDict[str, np.ndarray]" = collections.OrderedDict()


def _weights_at(scene: Scene, orientation) -> np.ndarray:
    """`compliant_weight` of `scene`'s drop at each orientation (rad)."""
    samples = eqx.tree_at(lambda s: s.drop.orientation, scene, jnp.asarray(orientation))
    return np.asarray(_weights(samples, sample_axes(samples, scene)))


def _orientation_weights(scene: Scene, key: str, orientation) -> np.ndarray:
    """`compliant_weight` of drops of `scene` that differ in their orientation alone: 0 between two nodes
    (orientations k `ORIENTATION_STEP`) where it is 0 (the near-flat bands are degrees wide), computed elsewhere;
    the weights at the nodes are kept for the last `_KEPT_TABLES` scenes. The rigid law and the next strike time
    of every drop took 3 us each on 2 cores; only about one drop in 15 of uniform orientations needs them."""
    grid = _GRID_WEIGHTS.get(key)
    grid = keep(_GRID_WEIGHTS, key, _weights_at(scene, np.arange(_node_count()) * ORIENTATION_STEP)
                if grid is None else grid, _KEPT_TABLES)
    k = np.floor(np.mod(orientation, 2 * math.pi) / ORIENTATION_STEP).astype(int) % grid.size
    near = np.flatnonzero((grid[k] > 0) | (grid[(k + 1) % grid.size] > 0))
    weight = np.zeros(orientation.shape[0])
    for start in range(0, near.size, _WEIGHT_CHUNK):
        part = near[start:start + _WEIGHT_CHUNK]
        padded = np.resize(orientation[part], _WEIGHT_CHUNK)
        weight[part] = _weights_at(scene, padded)[:part.size]
    return weight


def _node_count() -> int:
    return math.ceil(2 * math.pi / ORIENTATION_STEP)


def _nodes_around(orientation) -> np.ndarray:
    """The nodes k (orientations k `ORIENTATION_STEP`) on either side of each of these orientations (rad)."""
    k = np.floor(np.mod(orientation, 2 * math.pi) / ORIENTATION_STEP).astype(int) % _node_count()
    return np.unique(np.concatenate([k, (k + 1) % _node_count()]))


class OrientationTable(eqx.Module):
    """Peaks on the compliant landing's path at orientations k `ORIENTATION_STEP` (k in `nodes`) of one scene,
    read at other orientations by linear interpolation (`lookup`)."""

    nodes: np.ndarray
    values: tuple  # stress, strain, deflection, flags at the nodes

    def merged(self, other: "OrientationTable") -> "OrientationTable":
        """One table with both tables' nodes (this one's values where both hold a node)."""
        nodes = np.concatenate([self.nodes, other.nodes])
        nodes, first = np.unique(nodes, return_index=True)
        return OrientationTable(nodes, tuple(np.concatenate([a, b])[first] for a, b in zip(self.values, other.values)))

    def lookup(self, orientation):
        """(stress, strain, deflection, flags) at orientations (rad) between nodes; a drop whose neighbours are
        not both nodes gets NaN and `Flag.OUTSIDE_TABLE`."""
        count = _node_count()
        where = np.full(count, -1)
        where[self.nodes] = np.arange(self.nodes.size)
        u = np.mod(np.asarray(orientation, dtype=float), 2 * math.pi) / ORIENTATION_STEP
        k = np.minimum(np.floor(u).astype(int), count - 1)
        f = u - k
        a, b = where[k], where[(k + 1) % count]
        missing = (a < 0) | (b < 0)
        a, b = np.where(missing, 0, a), np.where(missing, 0, b)
        out = [np.where(missing, np.nan, (1 - f) * v[a] + f * v[b]) for v in self.values[:3]]
        flags = np.where(missing, int(Flag.OUTSIDE_TABLE), self.values[3][a] | self.values[3][b]).astype(np.int32)
        return out + [flags]


_KEPT_TABLES = 4
"""How many scenes' `orientation_table`s (and boards' superposition tables) `montecarlo` keeps in memory (the most
recently used), so that another run on the same scene solves only the nodes they lack and builds no table."""
_TABLES: "collections.OrderedDict[str, OrientationTable]" = collections.OrderedDict()
_SUPERPOSED: "collections.OrderedDict[str, object]" = collections.OrderedDict()


def _kept_superposition(scene: Scene, numerics: Numerics, durations, rolls: bool):
    """`superposition_table(scene, numerics, durations=durations, rolls=rolls)`, kept for the last `_KEPT_TABLES`
    boards, pulses and numerics asked for: another run on the same board reuses it (a plate's table takes about a
    second: 130 searches on the JESD22 board; over the sphere, 289)."""
    pulse = scene.contact.duration if durations is None else np.asarray(durations, dtype=np.float64)
    key = tree_digest((scene.board, pulse)) + repr((numerics, rolls))
    table = _SUPERPOSED.get(key)
    return keep(_SUPERPOSED, key, superposition_table(scene, numerics, durations=durations, rolls=rolls)
                if table is None else table, _KEPT_TABLES)


def forget_tables() -> None:
    """Drop every table `montecarlo` keeps (superposition tables, orientation tables and the grid's landing weights)
    and the plates' modes that `simulate` keeps: the next call builds what it needs, as a first call does
    (`beamdrop bench` times whole calls so)."""
    for kept in (_SUPERPOSED, _TABLES, _GRID_WEIGHTS):
        kept.clear()
    forget_modes()


def _missing_nodes(key: str, nodes) -> np.ndarray:
    kept = _TABLES.get(key)
    return np.asarray(nodes) if kept is None else np.setdiff1d(nodes, kept.nodes)


def _kept_table(scene: Scene, key: str, nodes, progress: bool) -> OrientationTable:
    """An `orientation_table` of `scene` holding `nodes`, from the one kept for it (`_KEPT_TABLES`), solving only the
    nodes it lacks."""
    missing = _missing_nodes(key, nodes)
    kept = _TABLES.get(key)
    if missing.size:
        new = orientation_table(scene, missing, progress)
        kept = new if kept is None else kept.merged(new)
    return keep(_TABLES, key, kept, _KEPT_TABLES)


def orientation_table(scene: Scene, nodes=None, progress: bool = False) -> OrientationTable:
    """The near-flat band of a plane section's drops over orientation: peaks on the compliant landing's path
    (`simulate`'s, default numerics but `TABLE_NUMERICS`' tolerance) at orientations k `ORIENTATION_STEP` for k in
    `nodes` (ints in [0, 7200), a full turn; default: every node whose drop, or a neighbour's, lands nearly flat;
    404 on the default scene). `montecarlo` uses it when
    only the orientation varies and the band holds more drops than the table has nodes: within 1 % of each drop's
    own solve (tests/test_montecarlo.py). Of nodes whose drops are mirror images (`_mirrors`) one is solved."""
    nodes = _orientation_nodes(scene) if nodes is None else _checked_nodes(nodes)
    solve, of_node = np.unique(_representatives(scene, nodes), return_inverse=True)
    samples = eqx.tree_at(lambda s: s.drop.orientation, scene, jnp.asarray(solve * ORIENTATION_STEP))
    values = solve_landings(samples, sample_axes(samples, scene), np.arange(solve.size), progress, TABLE_NUMERICS)
    return OrientationTable(nodes, tuple(np.asarray(v)[of_node] for v in values))


def _checked_nodes(nodes) -> np.ndarray:
    """`orientation_table`'s `nodes` as ints, or a `ValueError` naming what is not a node index."""
    given, count = np.atleast_1d(np.asarray(nodes)), _node_count()
    if given.ndim != 1 or given.size == 0 or not np.issubdtype(given.dtype, np.integer) or np.any(
            (given < 0) | (given >= count)):
        raise ValueError(f"nodes = {nodes!r}; valid: a non-empty list of ints in [0, {count}) (node k is the "
                         f"orientation k * {math.degrees(ORIENTATION_STEP):g} deg)")
    return given.astype(int)


def _mirrors(scene: Scene) -> tuple[str, ...]:
    """The mirror images among a concrete scene's drops over orientation, each a mirror in the vertical plane of
    the housing's first axis (gravity and the ground stay): `"x"`, the drop at -theta mirrors the drop at theta (a
    board that maps onto itself under x -> L - x, `mirror_symmetric`, centred on the housing's second axis); `"y"`,
    the drop at pi - theta mirrors it (the housing flipped over its first axis: a board centred on that axis). Both
    need a level board and a drop without spin or horizontal motion (a box's: untilted, nothing out of the plane).
    Mirror images have equal peaks (the landing's solver, corners taken in another order, agrees to its
    tolerance)."""
    if not is_concrete(scene):
        return ()
    d, p = scene.drop, scene.placement
    still = ("spin", "horizontal_speed") + (("tilt", "side_speed", "spin_x", "spin_y") if scene.housing.is_box else ())
    if not all(float(getattr(d, name)) == 0.0 for name in still) or float(p.angle) != 0.0:
        return ()
    centre = np.asarray(p.centre, dtype=float)
    return (("x",) if centre[0] == 0.0 and scene.board.mirror_symmetric() else ()) + (("y",) if centre[1] == 0.0 else ())


def _representatives(scene: Scene, nodes) -> np.ndarray:
    """The node each of `nodes` is solved as: the smallest of it and its mirror images (`_mirrors`; the node of
    orientation -theta, pi - theta, pi + theta)."""
    nodes, n = np.asarray(nodes, dtype=int), _node_count()
    mirrors = _mirrors(scene)
    images = [nodes] + ([(-nodes) % n] if "x" in mirrors else []) + ([(n // 2 - nodes) % n] if "y" in mirrors else [])
    if len(images) == 3:
        images.append((n // 2 + nodes) % n)
    return np.min(images, axis=0)


TABLE_NUMERICS = Numerics(landing_steps=FIRST_LANDING_STEPS, landing_tolerance=1e-6, landing_kinks=False)
"""The first solve of `orientation_table`'s nodes: its landings at a tolerance of 1e-6 (`simulate`'s: 1e-10),
stepping across the contacts' kinks (`Numerics.landing_kinks`: the table is read for values, not derivatives).
On the JESD22 plate's 105 solves (416 nodes; 2 cores) that took 2470 steps on average against 3060 with the kinks
closed in on (2.35 s against 2.97 s), and moved the nodes' peaks by at most 2.1e-4 of the largest from solves at 1e-10
(1.0e-4 with the kinks); on the default beam (102 solves, 404 nodes) 4.0e-5 (2.5e-5), in as many steps. The table's
linear interpolation errs by up to 5e-3."""


def landing_weights(scene: Scene, n: int, key, distribution: "DropDistribution | None" = None):
    """The compliant landing's weight (`compliant_weight`) of n random drops of `scene` drawn as `montecarlo`
    draws them: > 0 marks the near-flat drops that take the compliant path."""
    distribution = DropDistribution() if distribution is None else distribution
    samples = distribution.sample(scene, n, key)
    return _weights(samples, sample_axes(samples, scene), _from_rest(scene, samples))


@filter_jit
def _weights(samples, axes, from_rest: bool = False):
    def one(s):
        return compliant_weight(s, Numerics(from_rest=from_rest), housing_impact(s))

    return jax.vmap(one, in_axes=(axes,))(samples)
