"""Speed against accuracy: every method on the same random drops, timed in the same run, against a converged
reference, with two peers (a NumPy vectorised closed form and a SciPy `solve_ivp` loop per drop;
`_peers/numpy_scipy.py`).

Error: relative error of the peak stress against the closed form with 32 modes, refined peak, float64.
Time: seconds per drop, batched where the method allows, median of repeats after a warm-up run.
"""

import functools
import json
import math
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._common.checks import DEG

from ._impact.clatter import impact_sequence
from ._studies.montecarlo import (DropDistribution, evaluate_batch, forget_tables, inner_batch, landing_weights,
                                  montecarlo, montecarlo_numerics, sample_axes)
from ._scene.containers import Scene
from ._response.numerics import Numerics
from ._response.superposition import _batch_jumps, superposition_table, table_numerics
from ._common.compile import jit
from ._board.base import natural_frequencies
from ._board.beam import Board
from ._common.report import atomic_open
from ._impact.motion import HalfSine
from ._response.diffrax_path import solve_modes
from ._peers.numpy_scipy import (numpy_peak_stress, numpy_superposed_peak_stress, numpy_train_peak_stress,
                                 scipy_peak_stress)
from ._response.simulate import board_response, simulate
from ._response.surface import forget_modes
from ._scene.file import load_scene

REFERENCE = Numerics(n_modes=32)


def _alternating_medians(fns, repeats):
    """Median wall times of `fns` called in turn, `repeats` rounds after a warm-up: a machine whose speed drifts
    slows them alike, so their ratios hold (timed one after the other, a plate's drops against a beam's moved
    from 2.7x to 4.5x)."""
    for fn in fns:
        fn()
    times = [[] for _ in fns]
    for _ in range(repeats):
        for fn, out in zip(fns, times):
            t0 = time.perf_counter()
            fn()
            out.append(time.perf_counter() - t0)
    return [float(np.median(t)) for t in times]


def _median_time(fn, repeats):
    fn()  # warm-up (compilation)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _jax_method(samples, axes, numerics, repeats, f32=False):
    """Seconds per drop and peak stresses of one compiled, vmapped batch (the same drops for every method)."""
    n = int(samples.drop.orientation.shape[0])
    inner = inner_batch(numerics, n)  # as montecarlo runs it

    def run(batch):
        stress, _, _, _ = evaluate_batch(batch, axes, numerics, True, inner if n % inner == 0 else None)
        return np.asarray(jax.block_until_ready(stress), dtype=np.float64)

    if f32:
        with jax.enable_x64(False):
            batch = jax.tree_util.tree_map(lambda v: jnp.asarray(np.asarray(v), jnp.float32), samples)
            seconds = _median_time(lambda: run(batch), repeats)
            values = run(batch)
    else:
        seconds = _median_time(lambda: run(samples), repeats)
        values = run(samples)
    return seconds / n, values


# ---------------------------------------------------------------------------------------------------------------
# Peer 1: the same closed form, vectorised over drops in NumPy (Poisson impact, half-sine or impulse modes, grid).


LEVELS = ("tiny", "quick", "full")


def _peer_rows(add, scene, drops, axes, samples, tiled, peer_modes, peer_seconds, time_peer, big, whole_repeats, n,
               tiny, quick, repeats):
    """The peers' rows of `run_bench` on the fixed-duration workload: the NumPy closed form, the NumPy
    superposition and SciPy's `solve_ivp`."""
    for m in peer_modes:
        sec = min(peer_seconds[m], time_peer(m))
        add("peer: numpy closed form", f"n_modes={m} grid max, {tiled.size} drops", sec,
            numpy_peak_stress(scene, samples, m))
    # The same superposition in NumPy, on the same number of drops as the superposed row, in chunks of 65,536 (as
    # `montecarlo`'s; a whole 2^20 array per operation was slower); its table is given, not built, in its time.
    table = superposition_table(scene)
    many = np.resize(np.asarray(drops.drop.orientation), big)

    def numpy_superposed():
        return [numpy_superposed_peak_stress(scene, many[i:i + 65536], table) for i in range(0, big, 65536)]

    add("peer: numpy superposed", f"given table, {big} drops", _median_time(numpy_superposed, whole_repeats) / big,
        numpy_superposed_peak_stress(scene, samples, table))

    n_scipy = min(n, 1 if tiny else 8 if quick else 32)
    sub = jax.tree_util.tree_map(lambda v, a: v if a is None else v[:n_scipy], drops, axes)
    jumps, _ = _batch_jumps(sub, axes, "poisson", False)
    for method in ("RK45", "Radau"):
        t0 = time.perf_counter()
        vals = [scipy_peak_stress(scene, jumps[i], method)[0] for i in range(n_scipy)]
        add("peer: scipy solve_ivp", f"{method} rtol=1e-8 n_modes=6", (time.perf_counter() - t0) / n_scipy, vals)


def _rigid(scene: Scene) -> Scene:
    return eqx.tree_at(lambda s: s.contact, scene, scene.contact.with_model("rigid"))


def _print_plates(plates: dict) -> None:
    """`run_bench`'s progress line for `plate_bench`."""
    print(f"  near-flat drop on the compliant landing's path (0.5 deg): beam {plates['landing_beam_drop_ms']:.4g} ms "
          f"({plates['landing_beam_over_rigid']:.3g}x its rigid drop), plate {plates['landing_plate_drop_ms']:.4g} "
          f"ms ({plates['landing_plate_over_rigid']:.3g}x); share of uniform orientations on that path: beam "
          f"{100 * plates['landing_share_beam']:.2g} %, plate {100 * plates['landing_share_plate']:.2g} %")
    print(f"  plate drop (jesd22-board, 4 screws): {plates['plate_drop_ms']:.3g} ms, beam drop (default) "
          f"{plates['beam_drop_ms']:.3g} ms in the same run ({plates['plate_over_beam']:.3g}x); a new plate's first "
          f"drop (its modes solved in the call) {plates['new_plate_drop_ms']:.3g} ms "
          f"({plates['new_plate_over_beam']:.3g}x)\n"
          f"  superposed Monte-Carlo, {plates['montecarlo_drops']} drops, table build included: plate "
          f"{plates['plate_superposed_us_per_drop']:.3g} us/drop ({plates['plate_superposed_drops_per_s']:.3g} "
          f"drops/s), beam {plates['beam_superposed_us_per_drop']:.3g} us/drop; the plate's direct path "
          f"{plates['plate_direct_us_per_drop']:.3g} us/drop ({plates['plate_direct_over_superposed']:.3g}x); "
          "max error against a dense per-drop search (stress, strain, deflection): "
          + ", ".join(f"{v:.2g}" for v in plates["plate_superposed_max_error"].values()), flush=True)


def run_bench(scene: Scene | None = None, level: str = "quick", out=None, n_drops=None, repeats=None,
              progress=True) -> list[dict]:
    """Run the benchmark at `level` ("tiny": a smoke test of every part; "quick": < 5 min on 2 cores; "full");
    returns rows (method, settings, workload, seconds_per_drop, max_error, median_error, failures, drops, pareto)
    and, with `out`, writes `bench.json` (the rows and the stability study) there; `plot_bench` and
    `plot_stability` draw them. Two workloads of random drops: the scene's own contact duration (`FIXED`, every
    method), durations uniform on [0.2, 1] ms (`VARIED`: superposed Monte-Carlo and its NumPy peer) and up to 3
    impacts per drop (`CLATTER`: clattering Monte-Carlo and its NumPy peer), each with its own reference; `pareto` marks the rows no row of the same workload beats in time and error."""

    if level not in LEVELS:
        raise ValueError(f"level = {level!r}; valid: {', '.join(LEVELS)}")
    tiny, quick = level == "tiny", level == "quick"
    # Every method and peer here computes the first corner strike: the rigid law's drops (near-flat landings'
    # own path is timed by `plate_bench`).
    scene = _rigid(Scene.default() if scene is None else scene)
    n = n_drops or (8 if tiny else 256 if quick else 2048)
    repeats = repeats or (1 if tiny else 3 if quick else 5)
    key = jax.random.PRNGKey(2026)
    drops = DropDistribution().sample(scene, n, key)
    axes = sample_axes(drops, scene)
    samples = drops.drop.orientation
    # The NumPy peer on 4096 drops (the bench's own, repeated), where its per-call overhead is small; timed here,
    # before any JAX work, and again at the end, keeping its faster time (it ran 2x slower after the diffrax rows
    # in one run).
    tiled = np.resize(np.asarray(drops.drop.orientation), n if tiny else max(n, 4096))
    peer_modes = (4, 6)

    def time_peer(m):
        return _median_time(lambda: numpy_peak_stress(scene, tiled, m), repeats) / tiled.size

    peer_seconds = {m: time_peer(m) for m in peer_modes}
    references = {FIXED: np.asarray(montecarlo(scene, n, key, numerics=REFERENCE, progress=False).peak_stress)}
    rows = []

    def add(method, settings, seconds, values, workload=FIXED):
        values = np.asarray(values, float)
        idx = np.arange(values.size)
        err = np.abs(values / references[workload][idx] - 1)
        bad = ~np.isfinite(err)
        rows.append(dict(method=method, settings=settings, workload=workload, seconds_per_drop=seconds,
                         max_error=float(np.max(np.where(bad, np.inf, err))),
                         median_error=float(np.median(err[~bad])) if np.any(~bad) else float("inf"),
                         failures=int(bad.sum()), drops=int(values.size)))
        if progress:
            r = rows[-1]
            print(f"  {method:<22} {settings:<40} {r['seconds_per_drop'] * 1e6:10.3g} us/drop  "
                  f"max err {r['max_error']:.2e}" + ("" if workload == FIXED else f"  ({workload})"), flush=True)

    # "tiny" runs every kind of row once (each new setting is a new compilation): a smoke test, not a measurement.
    modes = (4,) if tiny else (2, 3, 4, 6, 8) if quick else (2, 3, 4, 6, 8, 12, 16)
    for m in modes:
        for refine in (True, False):
            num = Numerics(n_modes=m, refine=refine)
            sec, vals = _jax_method(drops, axes, num, repeats)
            add("closed_form", f"n_modes={m} refine={refine}", sec, vals)
    fast = montecarlo_numerics(scene)
    label = f"montecarlo default: n_modes={fast.n_modes} coarse"
    sec, vals = _jax_method(drops, axes, fast, repeats)
    add("closed_form", label, sec, vals)
    sec, vals = _jax_method(drops, axes, Numerics(n_modes=6), repeats, f32=True)
    add("closed_form f32", "n_modes=6 refine=True", sec, vals)
    if not tiny:
        sec, vals = _jax_method(drops, axes, fast, repeats, f32=True)
        add("closed_form f32", label, sec, vals)
    # Superposed: errors on the same drops; time per drop of whole `montecarlo` calls (table build, sampling and
    # transfers included) on many drops, the way it is used.
    big = n if tiny else 2**20  # tiny: the error run itself, timed (compilation included)
    whole_repeats = 1 if tiny else 7  # whole calls take ~0.1 s; their time varies by +-15 % from call to call
    sec, sup = _whole_calls(tiny, whole_repeats, scene, n, big, key, progress=False, superpose=True)
    add("montecarlo superposed", f"table of {table_numerics(scene).n_modes} modes x 256 directions, "
        f"whole call, {big} drops", sec, sup.peak_stress)

    # Contact durations uniform on [0.2, 1] ms: the table over durations, its errors against 32 modes searched per
    # drop; the NumPy closed form with per-drop durations as the peer (9 modes: what the table keeps for 0.2 ms).
    varied = DropDistribution(duration=("uniform", 2e-4, 1e-3))
    varied_drops = varied.sample(scene, n, key)
    sec, sup = _whole_calls(tiny, whole_repeats, scene, n, big, key, varied, progress=False)
    # tiny: a smoke test (as for clattering below), its own values as the reference: no 32-mode program to compile
    references[VARIED] = np.asarray(sup.peak_stress if tiny else montecarlo(
        scene, n, key, varied, REFERENCE, progress=False, superpose=False).peak_stress)
    varied_modes = table_numerics(scene, (2e-4, 1e-3)).n_modes
    add("montecarlo superposed", f"table of {varied_modes} modes x 17 durations x 128 directions, whole call, "
        f"{big} drops", sec, sup.peak_stress, VARIED)
    durations = np.resize(np.asarray(varied_drops.contact.duration), tiled.size)
    varied_orientations = np.resize(np.asarray(varied_drops.drop.orientation), tiled.size)

    def numpy_varied():
        return [numpy_peak_stress(scene, varied_orientations[i:i + 1024], varied_modes,
                                  durations=durations[i:i + 1024]) for i in range(0, tiled.size, 1024)]

    add("peer: numpy closed form", f"n_modes={varied_modes} grid max, {tiled.size} drops",
        _median_time(numpy_varied, repeats) / tiled.size,
        numpy_peak_stress(scene, varied_drops.drop.orientation, varied_modes, durations=varied_drops.contact.duration),
        VARIED)

    # Clattering, up to 3 impacts per drop: whole `montecarlo` calls with its clattering defaults, errors against
    # 32 modes searched per drop; the peer sums the same modes' shifted responses in NumPy, given the impacts.
    clatter = montecarlo_numerics(scene, max_impacts=3)
    reference = clatter if tiny else Numerics(n_modes=REFERENCE.n_modes, max_impacts=3)  # tiny: a smoke test
    references[CLATTER] = np.asarray(montecarlo(scene, n, key, numerics=reference, progress=False).peak_stress)
    many_clatter = n if tiny else 16384
    vals = montecarlo(scene, n, key, numerics=clatter, progress=False).peak_stress
    sec = _median_time(lambda: montecarlo(scene, many_clatter, key, numerics=clatter, progress=False),
                       repeats) / many_clatter
    add("montecarlo clattering", f"n_modes={clatter.n_modes}, {clatter.candidates} candidates ranked across impacts, "
        f"whole call, {many_clatter} drops", sec, vals, CLATTER)
    impacts = _batch_impacts(drops, axes)
    tile = n if tiny else max(n, 1024)
    times, jumps = (np.resize(np.asarray(v), (tile,) + v.shape[1:]) for v in (impacts.t, impacts.support_jumps))

    def numpy_clatter():
        return [numpy_train_peak_stress(scene, times[i:i + 256], jumps[i:i + 256], clatter.n_modes)
                for i in range(0, tile, 256)]

    add("peer: numpy closed form", f"n_modes={clatter.n_modes} grid max, given impacts, {tile} drops",
        _median_time(numpy_clatter, repeats) / tile,
        numpy_train_peak_stress(scene, impacts.t, impacts.support_jumps, clatter.n_modes), CLATTER)

    n_ode = min(n, 4 if tiny else 16 if quick else 64)
    solvers = ("Tsit5",) if tiny else ("Tsit5", "Dopri5", "Dopri8", "Kvaerno5", "ImplicitEuler")
    tolerances = (1e-4,) if tiny else (1e-6,) if quick else (1e-3, 1e-4, 1e-6, 1e-8)
    for solver in solvers:
        for rtol in tolerances:
            if solver == "ImplicitEuler" and rtol < 1e-4:
                continue  # first order: 1e-6 needs ~1e6 steps per drop
            num = Numerics(n_modes=6, method="diffrax", solver=solver, rtol=rtol, atol=rtol * 1e-4, max_steps=100000)
            sub = jax.tree_util.tree_map(lambda v, a: v if a is None else v[:n_ode], drops, axes)
            sec, vals = _jax_method(sub, axes, num, 1)
            add("diffrax", f"{solver} rtol={rtol:g} n_modes=6", sec, vals)

    _peer_rows(add, scene, drops, axes, samples, tiled, peer_modes, peer_seconds, time_peer, big, whole_repeats,
               n, tiny, quick, repeats)

    front = set(pareto_front(rows))
    for i, r in enumerate(rows):
        r["pareto"] = i in front
    study = stability_study(level, progress=progress)
    plates, boxes = (None, None) if tiny else _board_benches(quick, progress)
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)

        with atomic_open(out / "bench.json") as f:
            f.write(json.dumps(dict(drops=n, rows=rows, stability=study, plates=plates, boxes=boxes), indent=1))
    return rows


def _whole_calls(tiny, repeats, scene, n, big, *args, **kwargs):
    """(seconds per drop of whole `montecarlo` calls on `big` drops, the result on `n` drops): the median of
    `repeats` first calls after a warm-up; `tiny` (a smoke test, `big == n`): the one call, timed."""
    if tiny:
        start = time.perf_counter()
        result = _whole_call(scene, n, *args, **kwargs)
        return (time.perf_counter() - start) / n, result
    result = montecarlo(scene, n, *args, **kwargs)
    return _median_time(lambda: _whole_call(scene, big, *args, **kwargs), repeats) / big, result


def _whole_call(*args, **kwargs):
    """`montecarlo(*args, **kwargs)` as a first call makes it: every table it needs built in the call
    (`forget_tables`)."""
    forget_tables()
    return montecarlo(*args, **kwargs)


def landing_bench(n_drops: int = 1 << 20, scene: Scene | None = None, name: str = "landing") -> dict:
    """A whole `montecarlo` of `scene` (default: the default beam scene) over uniform orientations on `"auto"`
    (near-flat drops from an `orientation_table` built in the call; then, timed again with other drops, from the
    table it kept), against the same call on the rigid law (the first strike alone, the superposed fast path), after
    compiling: drops/s of each, the band's share, the table's nodes and the nodes solved (one of each set of mirror
    images), and the seconds per solved node; keys start with `name`."""
    from ._studies.montecarlo import _nodes_around, _representatives

    scene, key = Scene.default() if scene is None else scene, jax.random.PRNGKey(2026)
    rigid = _rigid(scene)
    montecarlo(rigid, n_drops, key, progress=False)
    montecarlo(scene, n_drops, jax.random.PRNGKey(1), progress=False)  # compiles every program of the call
    rigid_s = _median_time(lambda: _whole_call(rigid, n_drops, key, progress=False), 3)
    forget_tables()
    start = time.perf_counter()
    result = montecarlo(scene, n_drops, key, progress=False)
    auto_s = time.perf_counter() - start
    kept_s = _median_time(lambda: montecarlo(scene, n_drops, jax.random.PRNGKey(7), progress=False), 3)
    band = np.asarray(result.landing_weight) > 0
    nodes = _nodes_around(np.asarray(result.samples.drop.orientation)[band])
    solved = np.unique(_representatives(scene, nodes)).size
    out = dict(montecarlo_drops=n_drops, auto_drops_per_s=n_drops / auto_s, auto_kept_drops_per_s=n_drops / kept_s,
               rigid_drops_per_s=n_drops / rigid_s, band_share=float(band.mean()), table_nodes=nodes.size,
               table_solved=solved, seconds_per_node=(auto_s - rigid_s) / max(solved, 1))
    return {f"{name}_{k}": v for k, v in out.items()}


OFF_CENTRE = (0.005, 0.003)
"""Where `beamdrop bench` moves the default board (m from the housing's centre) for a scene without mirror images."""


def _print_landings(landings: dict, name: str = "landing", label: str = "default beam") -> None:
    """`run_bench`'s progress line for `landing_bench`."""
    r = {k[len(name) + 1:]: v for k, v in landings.items() if k.startswith(f"{name}_")}
    print(f"  Monte-Carlo over uniform orientations, {r['montecarlo_drops']} drops, {label}: \"auto\" "
          f"{r['auto_drops_per_s']:.3g} drops/s ({100 * r['band_share']:.2g} % near flat, from a table of "
          f"{r['table_nodes']} orientations built in the call, {r['table_solved']} solved (mirror images once) at "
          f"{r['seconds_per_node']:.3g} s each; {r['auto_kept_drops_per_s']:.3g} drops/s in later calls, the table "
          f"kept), \"rigid\" (first strike) {r['rigid_drops_per_s']:.3g} drops/s", flush=True)


def plate_bench(repeats: int = 5, n_drops: int = 1 << 20) -> dict:
    """Plates against beams, each pair timed in the same run (median wall times after compilation):
    - one `simulate` of the embedded `jesd22-board` plate (four screws) and of the default beam scene, alternated
      (6 `repeats` rounds); the plate's modes kept from an earlier drop of the same plate (`kept_modes`), and
      solved in the call (a new plate);
    - superposed Monte-Carlo: a whole `montecarlo` call on `n_drops` random orientations (table build included) on
      the plate and on the beam, and the plate's direct path (each drop's own search) on 64 drops; the superposed
      peaks' largest relative difference from a dense per-drop search (16 points per period, 8 candidates,
      8 Newton steps) over 256 drops."""
    import dataclasses


    plate, beam = _rigid(load_scene("jesd22-board")), _rigid(Scene.default())
    key = jax.random.PRNGKey(2026)

    def drop_time(scene):
        return _median_time(lambda: jax.block_until_ready(simulate(scene).peak.stress), repeats)

    def mc_time(scene, n, **kwargs):
        return _median_time(lambda: _whole_call(scene, n, key, progress=False, **kwargs), repeats) / n

    plate_drop, beam_drop = _alternating_medians(
        [lambda s=s: jax.block_until_ready(simulate(s).peak.stress) for s in (plate, beam)], 6 * repeats)
    new_plate_drop = _median_time(lambda: (forget_modes(), jax.block_until_ready(simulate(plate).peak.stress)), repeats)
    plate_mc, beam_mc = mc_time(plate, n_drops), mc_time(beam, n_drops)
    direct = mc_time(plate, 64, superpose=False)
    check = montecarlo(plate, 256, key, progress=False)
    dense = dataclasses.replace(table_numerics(plate), points_per_period=16, candidates=8, newton_steps=8)
    reference = evaluate_batch(check.samples, sample_axes(check.samples, plate), dense, False, 8)
    errors = [float(np.max(np.abs(np.asarray(found) / np.asarray(ref) - 1))) for found, ref in
              zip((check.peak_stress, check.peak_strain, check.peak_deflection), reference)]
    flat_beam, flat_plate = (eqx.tree_at(lambda s: (s.drop.orientation, s.contact), s,
                                         (jnp.asarray(0.5 * DEG), s.contact.with_model("auto"))) for s in (beam, plate))
    landing_beam, landing_plate = drop_time(flat_beam), drop_time(flat_plate)
    shares = [float(np.mean(np.asarray(landing_weights(s, 20000, key)) > 0)) for s in (flat_beam, flat_plate)]
    return dict(landing_beam_drop_ms=landing_beam * 1e3, landing_plate_drop_ms=landing_plate * 1e3,
                landing_beam_over_rigid=landing_beam / beam_drop, landing_plate_over_rigid=landing_plate / plate_drop,
                landing_share_beam=shares[0], landing_share_plate=shares[1],
                plate_drop_ms=plate_drop * 1e3, beam_drop_ms=beam_drop * 1e3, plate_over_beam=plate_drop / beam_drop,
                new_plate_drop_ms=new_plate_drop * 1e3, new_plate_over_beam=new_plate_drop / beam_drop,
                montecarlo_drops=n_drops, plate_superposed_us_per_drop=plate_mc * 1e6,
                plate_superposed_drops_per_s=1 / plate_mc, beam_superposed_us_per_drop=beam_mc * 1e6,
                plate_direct_us_per_drop=direct * 1e6, plate_superposed_over_beam=plate_mc / beam_mc,
                plate_direct_over_superposed=direct / plate_mc,
                plate_superposed_max_error=dict(zip(("stress", "strain", "deflection"), errors)))


def box_bench(repeats: int = 3, n_drops: int = 1 << 20) -> dict:
    """Box housings against plane sections, each pair timed in the same run (median wall times after compiling):
    a whole superposed `montecarlo` of the default beam in a 60 mm deep box over attitudes uniform on the rotation
    group (`DropDistribution.rotations()`: drops from rest, each one's 3D law in closed form) against the plane
    section over uniform orientations (`n_drops` each); one tilted `simulate` of the `phone` scene (a plate on
    eight screws) against the same plate at tilt 0 (the plane section's impact); a whole `montecarlo` of the
    JESD22 board in a 100 mm deep box over uniform attitudes (`n_drops`; its table over the sphere of jump
    directions built in the call), and that table's build alone."""
    key = jax.random.PRNGKey(2026)
    beam = _rigid(Scene.default())
    box = beam.replace(**{"housing.depth": 0.06})
    phone = _rigid(load_scene("phone"))

    def mc_time(scene, distribution):
        return _median_time(lambda: _whole_call(scene, n_drops, key, distribution, progress=False), repeats) / n_drops

    def drop_time(scene):
        return _median_time(lambda: jax.block_until_ready(simulate(scene).peak.stress), repeats)

    box_mc, plane_mc = mc_time(box, DropDistribution.rotations()), mc_time(beam, DropDistribution())
    tilted, flat = drop_time(phone), drop_time(phone.replace(**{"drop.tilt": 0.0}))
    # The JESD22 board in a 100 mm deep box: its table over the sphere of jump directions, built once per call.
    plate = _rigid(load_scene("jesd22-board")).replace(**{"housing.depth": 0.1})
    plate_mc = mc_time(plate, DropDistribution.rotations())
    build = _median_time(lambda: jax.block_until_ready(superposition_table(plate, rolls=True).fields), repeats)
    return dict(montecarlo_drops=n_drops, box_beam_drops_per_s=1 / box_mc, plane_beam_drops_per_s=1 / plane_mc,
                box_over_plane=box_mc / plane_mc, phone_tilted_drop_ms=tilted * 1e3, phone_tilt0_drop_ms=flat * 1e3,
                tilted_over_tilt0=tilted / flat, box_plate_drops_per_s=1 / plate_mc, box_plate_table_build_s=build,
                box_plate_drops_per_s_after_build=n_drops / (plate_mc * n_drops - build))


def _board_benches(quick: bool, progress: bool) -> tuple[dict, dict]:
    """`plate_bench`, `landing_bench` (the full level only, on the default beam, that beam off centre and the JESD22
    plate on `"auto"`: their tables take half a minute to a minute) and `box_bench`, each printed as
    it finishes with `progress`."""
    plates = plate_bench(repeats=5 if quick else 9)
    if progress:
        _print_plates(plates)
    if not quick:
        off = Scene.default().replace(**{"placement.centre": OFF_CENTRE})
        label = f"default beam moved to ({1e3 * OFF_CENTRE[0]:g}, {1e3 * OFF_CENTRE[1]:g}) mm (no mirror images)"
        jesd22 = load_scene("jesd22-board")
        jesd22 = eqx.tree_at(lambda s: s.contact, jesd22, jesd22.contact.with_model("auto"))
        for name, scene, text in (("landing", None, "default beam"), ("landing_off_centre", off, label),
                                  ("landing_jesd22", jesd22, "jesd22-board plate on 4 screws")):
            plates.update(landing_bench(scene=scene, name=name))
            if progress:
                _print_landings(plates, name, text)
    boxes = box_bench(repeats=3 if quick else 5)
    if progress:
        _print_boxes(boxes)
    return plates, boxes


def _print_boxes(boxes: dict) -> None:
    """`run_bench`'s progress line for `box_bench`."""
    print(f"  box housing, superposed Monte-Carlo over uniform attitudes ({boxes['montecarlo_drops']} drops, beam): "
          f"{boxes['box_beam_drops_per_s']:.3g} drops/s, against {boxes['plane_beam_drops_per_s']:.3g} drops/s for "
          f"the plane section over uniform orientations ({boxes['box_over_plane']:.3g}x the time); phone corner drop "
          f"{boxes['phone_tilted_drop_ms']:.3g} ms, at tilt 0 {boxes['phone_tilt0_drop_ms']:.3g} ms "
          f"({boxes['tilted_over_tilt0']:.3g}x); JESD22 plate in a box over uniform attitudes "
          f"{boxes['box_plate_drops_per_s']:.3g} drops/s with its table over the sphere built in the call "
          f"({boxes['box_plate_table_build_s']:.3g} s), {boxes['box_plate_drops_per_s_after_build']:.3g} drops/s "
          "after it", flush=True)


@functools.partial(jit, static_argnums=(1,))
def _batch_impacts(samples: Scene, axes):
    """Up to 3 impacts of each drop (the clattering peer's input), in one program: vmapped op by op, the search's
    loop compiled over a hundred small programs."""
    return jax.vmap(lambda d: impact_sequence(d, 3)[0], in_axes=(axes,))(samples)


FIXED = "fixed duration"
VARIED = "duration U[0.2, 1] ms"
CLATTER = "up to 3 impacts"


def pareto_front(rows) -> list[int]:
    """Indices of rows that no other row of the same workload (the same drops) beats in both time and max error."""
    front = []
    for i, r in enumerate(rows):
        rivals = [o for o in rows if o.get("workload", FIXED) == r.get("workload", FIXED)]
        dominated = any(
            (o["seconds_per_drop"] <= r["seconds_per_drop"] and o["max_error"] <= r["max_error"])
            and (o["seconds_per_drop"] < r["seconds_per_drop"] or o["max_error"] < r["max_error"])
            for o in rivals
        )
        if not dominated and math.isfinite(r["max_error"]):
            front.append(i)
    return front


PEERS = ("peer: numpy closed form", "peer: numpy superposed", "peer: scipy")


def ratio_at(rows, peer_prefix: str, tolerance: float = 0.01, workload: str = FIXED):
    """Speed ratio at `tolerance` max error on the drops of `workload`: fastest peer row over fastest beamdrop row
    that both meet it."""
    ok = [r for r in rows if r["max_error"] <= tolerance and r["failures"] == 0
          and r.get("workload", FIXED) == workload]
    ours = [r["seconds_per_drop"] for r in ok if not r["method"].startswith("peer")]
    peers = [r["seconds_per_drop"] for r in ok if r["method"].startswith(peer_prefix)]
    if not ours or not peers:
        return None
    return min(peers) / min(ours)


# ---------------------------------------------------------------------------------------------------------------
# Where methods fail: measured, not assumed.


def stability_study(level: str = "quick", progress=True) -> dict:
    """Measurements behind the stability map (returns a JSON-able dict; `plot_stability` draws it):

    - `stiffness`: diffrax steps and seconds per solve against the mode count, explicit vs implicit (rtol 1e-6);
    - `tolerance`: peak-stress error against rtol for each solver (6 modes, one drop), float64 and float32;
    - `modes`: peak stress against mode count for the ideal impulse and half-sines of several durations;
    - `buckling`: first frequency and peak stress as the axial compression approaches the Euler load.
    """


    tiny = level == "tiny"
    board = Board()
    motion = HalfSine(3.0, 1.0, 5e-4)
    out = {}

    def say(msg):
        if progress:
            print("  " + msg, flush=True)

    # Stiffness: the top mode's frequency grows like k^2.
    counts = (4,) if tiny else (4, 8, 16) if level == "quick" else (4, 8, 16, 32)
    solvers = ("Tsit5",) if tiny else ("Tsit5", "Dopri8", "Kvaerno5", "ImplicitEuler")
    rows = []
    for solver in solvers:
        for m in counts:
            window = jnp.asarray(5e-4 + 2 * math.pi / float(natural_frequencies(board, 1)[0]))
            rtol = 1e-3 if solver == "ImplicitEuler" else 1e-6

            @jit
            def solve(board, rtol=rtol, m=m, solver=solver):
                modes, failed = solve_modes(board, motion, m, window, jnp.ones(m), solver=solver, rtol=rtol,
                                            atol=rtol * 1e-6, max_steps=20000)
                return modes.solution.stats["num_steps"], failed

            jax.block_until_ready(solve(board))
            t0 = time.perf_counter()
            steps, failed = jax.block_until_ready(solve(board))
            sec = time.perf_counter() - t0
            top = float(natural_frequencies(board, m)[-1])
            rows.append(dict(solver=solver, rtol=rtol, n_modes=m, top_frequency_hz=top / (2 * math.pi),
                             steps=int(steps), seconds=sec, failed=bool(failed)))
            say(f"stiffness {solver:<13} {m:3d} modes: {int(steps):6d} steps {sec * 1e3:8.1f} ms "
                f"{'FAILED (max_steps)' if bool(failed) else ''}")
    out["stiffness"] = rows

    # Tolerance: error of the peak against the closed form, per solver, f64 and f32.
    exact = float(board_response(board, motion, Numerics(n_modes=6)).peak.stress)
    tolerances = (1e-3,) if tiny else (1e-2, 1e-4, 1e-6, 1e-8) if level == "quick" else (
        1e-2, 1e-3, 1e-4, 1e-6, 1e-8, 1e-10)
    rows = []
    for solver in ("Tsit5",) if tiny else ("Tsit5", "Dopri8", "Kvaerno5", "ImplicitEuler"):
        for rtol in tolerances:
            if solver == "ImplicitEuler" and rtol < 1e-4:
                continue
            for f32 in (False, True):
                num = Numerics(n_modes=6, method="diffrax", solver=solver, rtol=rtol, atol=rtol * 1e-6,
                               max_steps=50000)
                if f32:
                    with jax.enable_x64(False):
                        res = board_response(Board(), HalfSine(3.0, 1.0, 5e-4), num)
                        value, flags = float(res.peak.stress), int(res.flags)
                else:
                    res = board_response(board, motion, num)
                    value, flags = float(res.peak.stress), int(res.flags)
                err = abs(value / exact - 1) if math.isfinite(value) else float("inf")
                rows.append(dict(solver=solver, rtol=rtol, float32=f32, error=err, flags=flags))
                say(f"tolerance {solver:<13} rtol {rtol:7.0e} {'f32' if f32 else 'f64'}: error {err:.2e}"
                    f"{' flags ' + str(flags) if flags else ''}")
    out["tolerance"] = rows

    # Modes: ideal impulse against half-sines.
    counts = (2, 4) if tiny else (1, 2, 4, 8, 16, 32) if level == "quick" else (1, 2, 4, 8, 16, 32, 64)
    rows = []
    for tau in (0.0, 5e-5, 1e-4, 5e-4, 1e-3):
        for m in counts:
            value = float(board_response(board, HalfSine(3.0, 1.0, tau), Numerics(n_modes=m)).peak.stress)
            rows.append(dict(duration=tau, n_modes=m, stress=value))
        say(f"modes tau = {tau * 1e3:.2f} ms: " + ", ".join(f"{r['stress'] / 1e6:.1f}" for r in rows[-len(counts):]))
    out["modes"] = rows

    # Buckling: compression towards the Euler load.
    rows = []
    for ratio in ((0.0, 0.9) if tiny else (0.0, 0.5, 0.9, 0.99, 0.999)):
        b = Board(axial_force=-ratio * float(board.buckling_force))
        res = board_response(b, motion, Numerics(n_modes=6))
        rows.append(dict(load_ratio=ratio, f1_hz=float(res.frequencies[0]), stress=float(res.peak.stress),
                         window=float(res.window), search_error=float(res.peak.search_error)))
        say(f"buckling N/Ncr = {ratio}: f1 {rows[-1]['f1_hz']:.1f} Hz, peak {rows[-1]['stress'] / 1e6:.1f} MPa, "
            f"window {rows[-1]['window'] * 1e3:.1f} ms")
    out["buckling"] = rows
    return out


_BARE = "import jax, jax.numpy as jnp; jnp.zeros(1).block_until_ready()"
_FIRST = ("import time, jax; jax.config.update('jax_enable_x64', True); import beamdrop_jax as bd; "
          "s = bd.Scene.default(); t0 = time.perf_counter(); {call}; print(time.perf_counter() - t0)")
LATENCY_TARGETS = {  # name: (unit, target)
    "import_beamdrop_jax": ("x_bare", 1.3),
    "beamdrop_drop_cold_cache": ("x_bare", 3.0),
    "beamdrop_drop_warm_cache": ("x_bare", 1.5),
    "plate_drop_cold_cache": ("x_beam_cold", 3.0),
    "plate_drop_warm_cache": ("x_bare", 1.5),
    "first_simulate": ("s", 2.0),
    "first_grad_peak_stress": ("s", 3.0),
}


def latency_bench(repeats: int = 5) -> dict:
    """Time to first answer, in fresh Python processes, median of `repeats`: `import beamdrop_jax` (and, without a
    target, the import with a first `Scene.default()`, which loads JAX and the scene's modules) and `beamdrop
    drop --no-plots` (empty and warm compilation cache) as ratios to a bare JAX process timed in the same run, and
    `beamdrop drop --scene jesd22-board --no-plots` (a plate on four screws): empty cache against the beam's empty
    cache, warm against the bare process; the first `simulate` and the first `jax.grad(peak_stress)` in seconds
    (compile and run, no cache). Each with its target (`LATENCY_TARGETS`). The processes keep Python's bytecode
    cache whatever `PYTHONDONTWRITEBYTECODE` says: an installed package has its bytecode compiled at install, and a
    source checkout without it would time Python compiling the package's source."""
    import os
    import subprocess
    import sys
    import tempfile

    def wall(cmd, env=None):
        t0 = time.perf_counter()
        base = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        done = subprocess.run(cmd, capture_output=True, text=True, env={**base, **(env or {})})
        if done.returncode:
            raise RuntimeError(f"{' '.join(cmd)} failed: {done.stderr.strip().splitlines()[-1:]}")
        return time.perf_counter() - t0, done.stdout

    py = [sys.executable, "-c"]
    drop = [sys.executable, "-m", "beamdrop_jax.cli", "drop", "--no-plots"]
    plate = drop + ["--scene", "jesd22-board"]
    times = {k: [] for k in ("bare", "import", "scene", "cold", "warm", "plate_cold", "plate_warm", "simulate",
                             "grad")}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(repeats):
            times["bare"].append(wall(py + [_BARE])[0])
            times["import"].append(wall(py + ["import beamdrop_jax"])[0])
            times["scene"].append(wall(py + ["import beamdrop_jax as bd; bd.Scene.default()"])[0])
            cache = {"BEAMDROP_CACHE_DIR": str(Path(tmp) / f"cache{i}")}
            times["cold"].append(wall(drop, cache)[0])
            times["warm"].append(wall(drop, cache)[0])
            cache = {"BEAMDROP_CACHE_DIR": str(Path(tmp) / f"plate{i}")}
            times["plate_cold"].append(wall(plate, cache)[0])
            times["plate_warm"].append(wall(plate, cache)[0])
            times["simulate"].append(float(wall(py + [_FIRST.format(call="bd.simulate(s)")])[1]))
            grad = "jax.block_until_ready(jax.grad(bd.peak_stress)(s))"
            times["grad"].append(float(wall(py + [_FIRST.format(call=grad)])[1]))
    med = {k: float(np.median(v)) for k, v in times.items()}
    measured = {
        "import_beamdrop_jax": med["import"] / med["bare"],
        "beamdrop_drop_cold_cache": med["cold"] / med["bare"],
        "beamdrop_drop_warm_cache": med["warm"] / med["bare"],
        "plate_drop_cold_cache": med["plate_cold"] / med["cold"],
        "plate_drop_warm_cache": med["plate_warm"] / med["bare"],
        "first_simulate": med["simulate"],
        "first_grad_peak_stress": med["grad"],
    }
    # The import loads each module on first use: what a first call pays to reach the package, for the record.
    out = {"bare_jax_process_s": med["bare"], "import_and_default_scene_x_bare": med["scene"] / med["bare"]}
    for name, value in measured.items():
        suffix, target = LATENCY_TARGETS[name]
        out[f"{name}_{suffix}"] = value
        out[f"{name}_target_{suffix}"] = target
        out[f"{name}_met"] = value <= target
    return out
