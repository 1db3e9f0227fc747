"""The `beamdrop` command runs each job end to end and writes its files (smoke tests; numbers are tested
elsewhere)."""

import contextlib
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from beamdrop_jax.cli import main


@contextlib.contextmanager
def _through_the_programs_drop_kept():
    """Library calls in the block run the programs `beamdrop drop` kept (loaded, not compiled again: the same
    function, static arguments and shapes pick the same executable). A comparison with the command's numbers then
    checks what the command passes (the scene, settings and gauges pick the program and its arguments);
    `test_kept_programs_skip_tracing_and_give_the_same_numbers` checks kept programs against freshly compiled ones."""
    from beamdrop_jax._common.compile import keep_programs, quick_programs
    from beamdrop_jax.cli import _cache_dir

    with keep_programs(_cache_dir() / "programs"), quick_programs(True):
        yield


def test_drop_prints_summary_and_writes_figures(tmp_path, capsys):
    assert main(["drop", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "68.7" in out and "MPa" in out and "converged" in out
    for name in ("stress_map.png", "deflection.png", "impact.png"):
        assert (tmp_path / name).stat().st_size > 10_000


def test_impact_and_sensitivity(tmp_path, capsys):
    assert main(["impact", "--scene", "thesis", "--out", str(tmp_path)]) == 0
    assert "stick in compression" in capsys.readouterr().out
    assert main(["sensitivity", "--n-modes", "4", "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "drop.height" in out and "elasticity" in out


def test_montecarlo_and_optimize(tmp_path, capsys):
    assert main(["montecarlo", "-n", "300", "--n-modes", "4", "--allowable-microstrain", "2000",
                 "--out", str(tmp_path)]) == 0
    assert "probability over limit" in capsys.readouterr().out
    assert (tmp_path / "montecarlo.png").exists()
    assert main(["optimize", "--orientations", "30,60", "--steps", "3", "--starts", "1", "--n-modes", "4",
                 "--out", str(tmp_path)]) == 0
    assert "after objective (MPa)" in capsys.readouterr().out
    assert (tmp_path / "placement.png").exists()


def test_placement_figure_draws_supports_drop_directions_and_a_curve_where_the_board_fills_the_housing():
    import matplotlib

    matplotlib.use("Agg")
    import beamdrop_jax as bd

    scene = bd.Scene.default()
    scene = scene.replace(**{"board.length": 0.148})  # at angle 0, 1 mm of room along the width, 75 mm along the height
    numerics = bd.Numerics(n_modes=4)
    orientations = np.radians([20.0, 50.0])
    res = bd.optimize_placement(scene, orientations, numerics=numerics, steps=2, starts=1, max_angle=0.0,
                                progress=False)
    c1, c2, values = bd.placement_landscape(scene, res, orientations, numerics=numerics, n=(9, 5))
    assert c1.shape == (1,) and c2.shape == (5,) and values.shape == (1, 5)
    np.testing.assert_allclose(c2[[0, -1]], [-0.0375, 0.0375], rtol=1e-12)  # H/2 - L/2 |sin 0|
    fig = bd.plot_placement(scene, res, (c1, c2, values), orientations=orientations)
    curve, board = fig.axes[0], fig.axes[-1]
    assert not curve.collections  # a curve over c2, not a map
    np.testing.assert_allclose(curve.lines[0].get_xdata(), c2 * 1e3)
    assert "fills the housing's width" in curve.get_title()
    supports = next(line for line in board.lines if line.get_label() == "supports (ends A, B)")
    centre, angle = np.asarray(res.placement.centre), float(res.placement.angle)
    ends = centre + np.outer([-0.074, 0.074], [math.cos(angle), math.sin(angle)])
    np.testing.assert_allclose(np.c_[supports.get_xdata(), supports.get_ydata()], ends * 1e3, atol=1e-9)
    arrows = [a for a in board.texts if a.arrow_patch is not None]
    assert len(arrows) == 2
    for arrow, theta in zip(arrows, orientations):
        tip = np.asarray(arrow.xy)
        np.testing.assert_allclose(tip / np.linalg.norm(tip), [-math.sin(theta), -math.cos(theta)], atol=1e-12)


def test_bench_tiny_writes_table_and_chart(tmp_path):
    assert main(["bench", "--tiny", "--out", str(tmp_path)]) == 0
    table = json.loads((tmp_path / "bench.json").read_text())
    methods = {r["method"] for r in table["rows"]}
    assert {"closed_form", "diffrax", "peer: numpy closed form", "peer: numpy superposed",
            "peer: scipy solve_ivp"} <= methods
    for r in table["rows"]:
        assert r["seconds_per_drop"] > 0 and r["max_error"] >= 0
    assert (tmp_path / "bench.png").stat().st_size > 10_000


def test_bad_scene_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[contact]\nrestitution = 1.5\n")
    assert main(["drop", "--scene", str(bad), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "restitution = 1.5" in err and "[0, 1]" in err


def test_drop_with_clattering_prints_the_impacts(capsys):
    assert main(["drop", "--max-impacts", "3", "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "Impacts (3 of at most 3" in out and "17.442" in out


def test_pivot_is_a_clear_cli_error_and_clattering_montecarlo_runs(tmp_path, capsys):
    scene = tmp_path / "e0.toml"
    import beamdrop_jax as bd

    bd.save_scene(bd.Scene.default().replace(**{"contact.restitution": 0.0}), scene)
    assert main(["drop", "--scene", str(scene), "--max-impacts", "3", "--no-plots"]) == 2
    assert "pivot phase" in capsys.readouterr().err
    assert main(["montecarlo", "-n", "64", "--max-impacts", "2", "--allowable-microstrain", "2000",
                 "--no-plots"]) == 0
    assert "64 random drops" in capsys.readouterr().out


def test_programs_compile_with_classic_emitters_only_where_jax_allows_and_the_user_has_not_chosen(monkeypatch):
    """A package program called on its own compiles with XLA's classic-emitter option; traced into a user's `jit`,
    `grad` or `vmap` (where JAX refuses options) it compiles as usual, with the same numbers; `XLA_FLAGS` that
    set the emitters, or a jaxlib without the option, leave compilation as it is."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from beamdrop_jax._common import compile as _compile

    monkeypatch.setenv("XLA_FLAGS", "")  # a user's process (the test run sets the emitters itself)
    _compile.compiler_options.cache_clear()
    try:
        assert _compile.compiler_options() == {"xla_cpu_use_fusion_emitters": False}
        f = _compile.filter_jit(lambda x: jnp.sin(2 * x) ** 2)
        plain_calls = []
        plain = f._program(False, False)
        f._programs[False, False] = lambda *a: plain_calls.append(1) or plain(*a)
        x = jnp.asarray(0.3)
        value, slope = np.sin(0.6) ** 2, 4 * np.sin(0.6) * np.cos(0.6)
        np.testing.assert_allclose(float(f(x)), value, rtol=1e-14)
        assert plain_calls == [] and f._programs[False, True] is not plain  # on its own: the program with the option
        np.testing.assert_allclose(float(jax.jit(f)(x)), value, rtol=1e-14)
        np.testing.assert_allclose(float(jax.grad(f)(x)), slope, rtol=1e-14)
        np.testing.assert_allclose(float(jax.jit(jax.grad(f))(x)), slope, rtol=1e-14)
        np.testing.assert_allclose(np.asarray(jax.vmap(f)(jnp.stack([x, x]))), [value, value], rtol=1e-14)
        np.testing.assert_allclose(float(jax.jit(lambda: f(x))()), value, rtol=1e-14)  # no traced argument
        assert len(plain_calls) == 5
        # Programs that ask for YNNPACK's product fusions only (Monte-Carlo chunks): the same numbers.
        dots = {"xla_cpu_experimental_ynn_fusion_type": "LIBRARY_FUSION_TYPE_DOT"}
        assert _compile.compiler_options(True) == {"xla_cpu_use_fusion_emitters": False, **dots}
        a = np.random.default_rng(0).normal(size=(40, 7))
        grid_max = _compile.filter_jit(dot_fusions_only=True)(lambda m: jnp.abs(m @ m[:9].T).max(axis=0))
        np.testing.assert_allclose(np.asarray(grid_max(jnp.asarray(a))), np.abs(a @ a[:9].T).max(axis=0), rtol=1e-14)
        monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true")
        _compile.compiler_options.cache_clear()
        assert _compile.compiler_options() is None
        assert _compile.compiler_options(True) == dots
        monkeypatch.setenv("XLA_FLAGS", "")
        monkeypatch.setattr(_compile, "_CLASSIC_EMITTERS", "xla_cpu_no_such_option_for_beamdrop")
        _compile.compiler_options.cache_clear()
        assert _compile.compiler_options() is None
        assert _compile.compiler_options(True) == dots  # each option checked on its own when together they fail
    finally:
        monkeypatch.undo()
        _compile.compiler_options.cache_clear()


def test_quick_programs_are_smaller_and_give_the_same_numbers(tmp_path, monkeypatch):
    """Under `quick_programs` (the CLI's single drop) a program is traced with XLA's own sine and cosine, not the
    polynomial ones, and compiled without LLVM's optimisation passes: a third fewer operations in the drop's
    program, the same peaks to 1e-12. Kept programs keep the two kinds apart; outside the block, the usual one."""
    import random

    import jax
    import numpy as np

    import beamdrop_jax as bd
    from beamdrop_jax._common import compile as _compile, trig as _trig
    from beamdrop_jax._response import simulate as _simulate

    def primitives(fun, *args):  # traced anew (a fresh function: no trace cache); inner programs' too
        def walk(jaxpr):
            for eqn in jaxpr.eqns:
                inner = [getattr(v, "jaxpr", v) for p in eqn.params.values() for v in (p if isinstance(p, tuple)
                                                                                       else (p,))]
                inner = [v for v in inner if isinstance(v, jax.extend.core.Jaxpr)]
                yield from (name for j in inner for name in walk(j)) if inner else (eqn.primitive.name,)

        return list(walk(jax.make_jaxpr(lambda *a: fun(*a))(*args).jaxpr))

    scene, numerics = bd.Scene.default(), bd.Numerics(n_modes=5)
    usual = bd.simulate(scene, numerics)
    usual_size = len(primitives(lambda s: _simulate._simulate(s, numerics), scene))
    assert "sin" not in primitives(_trig.sincos, 0.3)
    with _compile.quick_programs():
        assert primitives(_trig.sincos, 0.3) == ["sin", "cos"]
        assert len(primitives(lambda s: _simulate._simulate(s, numerics), scene)) < 0.75 * usual_size
        quick = bd.simulate(scene, numerics)
        with _compile.quick_programs(False):  # the innermost block decides
            assert "sin" not in primitives(_trig.sincos, 0.3)
    assert not _compile.is_quick() and (True, True) in _simulate._simulate_jit._programs
    # Traced into another program (here `vmap`), a quick trace is not reused outside the block, nor the reverse.
    first_sine = _compile.filter_jit(lambda x: _trig.sincos(x)[0])
    with _compile.quick_programs():
        assert "sin" in primitives(jax.vmap(first_sine), np.zeros(3))
    assert "sin" not in primitives(jax.vmap(first_sine), np.zeros(3))
    with _compile.quick_programs():
        assert "sin" in primitives(jax.vmap(first_sine), np.zeros(3))
    for get in (lambda r: r.peak.stress, lambda r: r.peak.x, lambda r: r.peak.t, lambda r: r.peak.deflection,
                lambda r: r.error_estimate, lambda r: r.impulse.P):
        np.testing.assert_allclose(np.asarray(get(quick)), np.asarray(get(usual)), rtol=1e-12, atol=0)
    monkeypatch.setenv("XLA_FLAGS", "")  # a user's process (the test run sets the level itself)
    _compile.compiler_options.cache_clear()
    try:
        assert _compile.compiler_options(quick=True) == {"xla_cpu_use_fusion_emitters": False,
                                                          "xla_backend_optimization_level": 0}
    finally:
        monkeypatch.undo()
        _compile.compiler_options.cache_clear()
    # A tolerance of this run only: programs JAX's compilation cache (shared by the test runs) has never seen.
    numerics = bd.Numerics(n_modes=5, convergence_rtol=1e-3 * (1 + random.random()))
    folder = tmp_path / "programs"
    with _compile.keep_programs(folder):
        bd.simulate(scene, numerics)
        with _compile.quick_programs():
            kept_quick = bd.simulate(scene, numerics)
    assert len(list(folder.iterdir())) == 2
    np.testing.assert_allclose(float(kept_quick.peak.stress), float(usual.peak.stress), rtol=1e-12)


def test_the_command_flushes_its_output_and_stops_quietly_when_the_reader_goes(tmp_path):
    """`beamdrop` (`cli.run`) ends without Python's teardown: its output arrives whole first; a reader that goes
    away early (`beamdrop drop | head`) ends it without a traceback."""
    command = [sys.executable, "-m", "beamdrop_jax.cli", "drop", "--no-plots", "--n-modes", "4"]
    done = subprocess.run(command + ["--json"], capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["n_modes"] == 4 and report["peak_stress_MPa"] > 0
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path)
    proc.stdout.close()  # the reader is gone before the first line
    _, err = proc.communicate(timeout=300)
    assert proc.returncode in (0, 1) and b"Traceback" not in err and b"BrokenPipe" not in err, err.decode()


def test_a_plate_command_runs_twice_on_one_cache(tmp_path):
    """A kept plate program calls LAPACK (`eigh`), which a process that loads it without compiling has not
    initialised: the second run on one cache once ended in a segmentation fault. Two processes, one cache, the
    same numbers. The second run loads the program ahead (`preload_programs`: its command line ran before); a third
    command line, new to the cache, loads it when it is called. Setting LAPACK up imports SciPy's two Cython
    modules, not the whole of `scipy.linalg` (a sixth of a warm plate run)."""
    args = ["drop", "--scene", "jesd22-board", "--no-plots", "--json", "--out"]
    command = [sys.executable, "-m", "beamdrop_jax.cli", *args]
    # The second run as the command runs it (`main` on the same arguments), telling what it imported.
    reporting = [sys.executable, "-c", "import sys; from beamdrop_jax.cli import main; code = main(sys.argv[1:]); "
                 "print('imported scipy.linalg:', 'scipy.linalg' in sys.modules, file=sys.stderr); sys.exit(code)",
                 *args]
    env = {**os.environ, "BEAMDROP_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("BEAMDROP_NO_CACHE", None)
    runs = [subprocess.run(line + [str(tmp_path / out)], capture_output=True, text=True, env=env, timeout=300)
            for line, out in ((command, "out"), (reporting, "out"), (command, "other"))]
    assert [run.returncode for run in runs] == [0, 0, 0], runs[-1].stderr[-2000:]
    assert "compiling" in runs[0].stderr and not any("compiling" in run.stderr for run in runs[1:])
    assert "imported scipy.linalg: False" in runs[1].stderr, runs[1].stderr[-2000:]
    first, second, third = (json.loads(run.stdout) for run in runs)
    assert first["peak_strain_microstrain"] == second["peak_strain_microstrain"] == third["peak_strain_microstrain"] > 0


def test_single_drop_commands_compile_a_few_programs_not_one_per_operation(tmp_path):
    """JAX run eagerly compiles one program per operation (20 ms each): the commands' eager work (the impact, the
    support jumps, the scene check, the figures' geometry) runs as one compiled program each or as NumPy. Counted
    in a fresh process with the cache off (operation by operation, `beamdrop impact` alone compiles over 60)."""
    script = """
import sys, jax
compiles = []
jax.monitoring.register_event_duration_secs_listener(
    lambda event, duration, **kw: compiles.append(1) if event == "/jax/core/compile/backend_compile_duration" else 0)
from beamdrop_jax.cli import main
for command in ("impact", "drop"):
    before = len(compiles)
    assert main([command, "--no-cache", "--out", sys.argv[1]]) == 0
    print(command, len(compiles) - before, file=sys.stderr)
"""
    done = subprocess.run([sys.executable, "-c", script, str(tmp_path)], capture_output=True, text=True,
                          timeout=300, env={**os.environ, "BEAMDROP_NO_CACHE": "1"})
    assert done.returncode == 0, done.stderr
    counts = dict(line.split() for line in done.stderr.splitlines() if line.startswith(("impact ", "drop ")))
    # impact: the impact, the support jumps, the diagram's impulse path, the compile options' check; drop: its
    # drop and its scene check (the rest is shared with impact).
    assert int(counts["impact"]) <= 4 and int(counts["drop"]) <= 3, counts


def test_kept_programs_skip_tracing_and_give_the_same_numbers(tmp_path, monkeypatch):
    """`keep_programs` (the CLI's cache): a call compiles and keeps its program once; a later process (here: an
    empty in-process table and a function that must not be traced) loads it and gets the numbers of the usual path.
    Other static arguments or another package source are new entries; closures are not kept; a program that JAX's
    own compilation cache supplied (its folder of kept programs lost) is used but not kept (it would not serialise
    whole)."""
    import random

    import jax.numpy as jnp
    import numpy as np

    import beamdrop_jax as bd
    from beamdrop_jax._common import compile as _compile
    from beamdrop_jax._response import simulate as _simulate

    # A tolerance of this run only: a program JAX's compilation cache (shared by the test runs) has never seen.
    scene, numerics = bd.Scene.default(), bd.Numerics(n_modes=5, convergence_rtol=1e-3 * (1 + random.random()))
    usual = bd.simulate(scene, numerics)
    program = _simulate._simulate_jit
    folder = tmp_path / "programs"
    with _compile.keep_programs(folder):
        first = bd.simulate(scene, numerics)
        kept = sorted(p.name for p in folder.iterdir())
        assert len(kept) == 1 and kept[0].startswith("_simulate-")
        program._loaded.clear()  # a new process: only the folder remains
        traced = []

        def untraceable(*args, **kwargs):
            traced.append(1)
            raise AssertionError("traced again")

        monkeypatch.setattr(program, "_fun", untraceable)
        os.utime(folder / kept[0], (1e9, 1e9))
        again = bd.simulate(scene, numerics)
        assert traced == [] and len(program._loaded) == 1  # loaded from the folder
        assert (folder / kept[0]).stat().st_mtime > 1.7e9  # and marked as used now, for `prune_folder`
        # Loaded ahead by `preload_programs` (the CLI's next run of a command line): the call takes it from there.
        program._loaded.clear()
        (folder / "broken.xla").write_bytes(b"not a program")
        _compile.preload_programs(folder, [kept[0], "broken.xla", "absent.xla"]).join()
        assert _compile._preloaded[folder / kept[0]].exception() is None
        assert _compile._preloaded[folder / "broken.xla"].exception() is not None
        monkeypatch.setattr(_compile, "_deserialise", lambda data: pytest.fail("loaded again"))
        preloaded = bd.simulate(scene, numerics)
        assert folder / kept[0] not in _compile._preloaded and traced == []
        (folder / "broken.xla").unlink()
        _compile._preloaded.clear()
        for res in (first, again, preloaded):
            for get in (lambda r: r.peak.stress, lambda r: r.peak.x, lambda r: r.peak.t, lambda r: r.frequencies,
                        lambda r: r.support_jumps, lambda r: r.error_estimate, lambda r: r.impulse.P):
                np.testing.assert_allclose(np.asarray(get(res)), np.asarray(get(usual)), rtol=1e-13, atol=0)
            assert int(res.flags) == 0 and res.summary()["contact_mode"] == usual.summary()["contact_mode"]
        monkeypatch.undo()
        program._loaded.clear()
        bd.simulate(scene, bd.Numerics(n_modes=5, convergence_rtol=2e-3 * (1 + random.random())))  # static argument
        assert len(list(folder.iterdir())) == 2
        bd.simulate(scene, numerics, gauges=None)  # the same call
        assert len(list(folder.iterdir())) == 2
        monkeypatch.setattr(_compile, "_environment", lambda: "another package source")
        bd.simulate(scene, numerics)
        monkeypatch.undo()
        assert len(program._loaded) == 3 and len(list(folder.iterdir())) == 3
        f = _compile.filter_jit(lambda x: 2 * x)  # a closure: its name does not say what it captured
        assert float(f(jnp.asarray(1.5))) == 3.0
        assert len(list(folder.iterdir())) == 3
    program._loaded.clear()
    with _compile.keep_programs(tmp_path / "other"):  # in JAX's compilation cache since the first call above
        res = bd.simulate(scene, numerics)
        np.testing.assert_allclose(float(res.peak.stress), float(usual.peak.stress), rtol=1e-13)
        assert not (tmp_path / "other").exists()


def test_cli_lists_the_programs_a_command_line_used_and_loads_them_ahead_next_time(tmp_path, monkeypatch, capsys):
    """After a run with the cache, the programs it used are listed for its command line (and folder); the next run
    of that line starts loading them before it parses, and prints the same; another line, or no cache, lists
    nothing and loads nothing ahead."""
    from beamdrop_jax import cli
    from beamdrop_jax._common import compile as _compile

    monkeypatch.setenv("BEAMDROP_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    argv = ["drop", "--no-plots", "--n-modes", "5"]
    assert cli._preload(cli._run_record(argv)) == ((), None)
    assert cli.main(argv) == 0
    first = capsys.readouterr().out
    listed = json.loads(cli._run_record(argv).read_text())
    assert len(listed) == 1 and listed[0].startswith("_simulate-")
    assert (tmp_path / "cache" / "programs" / listed[0]).exists()
    started = []
    preload = _compile.preload_programs
    monkeypatch.setattr(_compile, "preload_programs", lambda folder, names: started.append(names) or preload(
        folder, names))
    assert cli.main(argv) == 0
    assert started == [listed] and capsys.readouterr().out == first
    _compile._preloaded.clear()
    assert cli._run_record(argv + ["--no-cache"]) is None and cli._run_record(["drop"]) != cli._run_record(argv)
    monkeypatch.setenv("BEAMDROP_NO_CACHE", "1")
    assert cli._run_record(argv) is None


def test_cache_keeps_its_size_by_removing_the_least_recently_used(tmp_path, monkeypatch):
    """`prune_folder` removes the oldest files first until the rest fit; the CLI prunes its cache after a run that
    compiled (no stamp yet for its settings), never the stamps, and not after a warm run."""
    from beamdrop_jax import cli
    from beamdrop_jax._common import compile as _compile

    folder = tmp_path / "xla"
    (folder / "programs").mkdir(parents=True)
    files = {"compiled-aaaa": 0, "old-cache": 400, "programs/mid.xla": 300, "new-cache": 300}
    for age, (name, size) in enumerate(files.items()):
        (folder / name).write_bytes(b"x" * size)
        os.utime(folder / name, (1e9 + age, 1e9 + age))
    stamps = lambda path: path.name.startswith("compiled-")  # noqa: E731
    assert _compile.prune_folder(folder, 10_000) == 0
    assert _compile.prune_folder(folder, 700, keep=stamps) == 400
    assert sorted(p.name for p in folder.rglob("*") if p.is_file()) == ["compiled-aaaa", "mid.xla", "new-cache"]
    monkeypatch.setattr(cli, "CACHE_MAX_BYTES", 300)
    cli._bound_cache(folder / "compiled-aaaa")  # a warm run: nothing removed
    assert (folder / "programs" / "mid.xla").exists()
    cli._bound_cache(folder / "compiled-bbbb")  # a run that compiled
    assert sorted(p.name for p in folder.rglob("*") if p.is_file()) == ["compiled-aaaa", "compiled-bbbb",
                                                                         "new-cache"]


# ---------------------------------------------------------------------------------------------------------------
# Data safety: output files appear complete or not at all; interrupts and impossible sizes are one line.


def _leftovers(folder):
    return sorted(p.name for p in folder.iterdir())


def test_a_failed_csv_write_leaves_no_file_under_the_final_name(tmp_path):
    from beamdrop_jax._common.report import write_csv

    class Unreadable:
        def __float__(self):
            raise OSError(28, "No space left on device")

    with pytest.raises(OSError):
        write_csv([{"a_mm": 1.0}, {"a_mm": Unreadable()}], tmp_path / "table.csv")
    assert _leftovers(tmp_path) == []  # neither a header-only table.csv nor its temporary file
    write_csv([{"a_mm": 1.0}, {"a_mm": 2.0}], tmp_path / "table.csv")
    assert _leftovers(tmp_path) == ["table.csv"]
    assert (tmp_path / "table.csv").read_text().splitlines() == ["a_mm", "1.0", "2.0"]


def test_a_figure_that_fails_half_written_leaves_no_png(tmp_path, monkeypatch):
    import matplotlib.figure

    real = matplotlib.figure.Figure.savefig

    def half_then_full_disk(self, fname, *args, **kwargs):
        if hasattr(fname, "write"):
            fname.write(b"\x89PNG\r\n\x1a\n")
        else:
            with open(fname, "wb") as f:
                f.write(b"\x89PNG\r\n\x1a\n")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", half_then_full_disk)
    with pytest.raises(OSError):
        main(["impact", "--out", str(tmp_path)])
    assert _leftovers(tmp_path) == []
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", real)
    assert main(["impact", "--out", str(tmp_path)]) == 0
    assert _leftovers(tmp_path) == ["impact.png"]
    assert (tmp_path / "impact.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_columns_csv_is_the_text_of_the_rows_csv(tmp_path):
    """The bulk writer writes what `csv` wrote a dict per row: shortest round-trip floats, NaN and inf empty,
    integers, booleans, quoted strings, \\r\\n line ends; over several blocks of rows."""
    from beamdrop_jax._common import report as _report

    rng = np.random.default_rng(1)
    n = 2 * _report._BLOCK_ROWS + 7
    x = rng.standard_normal(n) * 10.0 ** rng.integers(-30, 30, n)
    x[[3, 70_000, n - 1]] = [np.nan, np.inf, -0.0]
    columns = {"x_mm": x, "k": rng.integers(-5, 5, n).astype(np.int32), "ok": rng.random(n) < 0.5,
               "flags": np.array(["", "A|B", 'say "hi", twice', "line\nbreak"], dtype=object)[rng.integers(0, 4, n)]}
    rows = [dict(zip(columns, values)) for values in zip(*(v.tolist() for v in columns.values()))]
    _report.write_csv(rows, tmp_path / "rows.csv")
    _report.write_csv_columns(columns, tmp_path / "columns.csv")
    assert (tmp_path / "columns.csv").read_bytes() == (tmp_path / "rows.csv").read_bytes()
    _report.write_csv([{"a": None}, {"a": 1.5}], tmp_path / "one_rows.csv")
    _report.write_csv_columns({"a": np.array([np.nan, 1.5])}, tmp_path / "one_columns.csv")
    assert (tmp_path / "one_columns.csv").read_bytes() == (tmp_path / "one_rows.csv").read_bytes()


def test_montecarlo_csv_holds_the_result_arrays_and_shows_its_progress(tmp_path, monkeypatch, capsys):
    import csv
    import math

    import beamdrop_jax as bd
    from beamdrop_jax._common import report as _report

    results = []
    montecarlo = bd.montecarlo
    monkeypatch.setattr(bd, "montecarlo", lambda *a, **k: results.append(montecarlo(*a, **k)) or results[-1])
    monkeypatch.setattr(_report, "PROGRESS_ROWS", 1000, raising=False)  # a "large" table for this test
    assert main(["montecarlo", "-n", "3000", "--allowable-microstrain", "2000", "--no-plots", "--contact-model", "rigid",
                 "--out", str(tmp_path)]) == 0
    assert "writing montecarlo-drops.csv" in capsys.readouterr().err
    res, = results
    with open(tmp_path / "montecarlo-drops.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert len(table) == 3000
    assert list(table[0]) == ["orientation_deg", "peak_stress_MPa", "peak_strain_microstrain", "peak_deflection_mm",
                              "flags"]
    expected = {"orientation_deg": np.degrees(np.asarray(res.samples.drop.orientation)),
                "peak_stress_MPa": np.asarray(res.peak_stress) / 1e6,
                "peak_strain_microstrain": np.asarray(res.peak_strain) * 1e6,
                "peak_deflection_mm": np.asarray(res.peak_deflection) * 1e3}
    for name, values in expected.items():
        read = np.array([float(r[name]) if r[name] else math.nan for r in table])
        np.testing.assert_array_equal(read, values, err_msg=name)  # every digit: the floats read back exactly
    assert [r["flags"] for r in table] == ["|".join(bd.Flag.describe(f)) for f in np.asarray(res.flags).tolist()]
    assert _leftovers(tmp_path) == ["montecarlo-drops.csv"]


def _interrupt(tmp_path, argv, marker, after_s=0.0, env=None):
    """Start `beamdrop ARGV` (`python -m beamdrop_jax.cli`), send SIGINT `after_s` seconds after `marker` appears
    on its stderr; returns (exit status, stderr, seconds from the signal to the exit)."""
    import signal
    import threading
    import time

    # As from a terminal: a test run started in the background (`pytest &` in a script) ignores SIGINT, and a
    # child inherits that; the command rightly leaves an ignored SIGINT ignored.
    as_from_a_terminal = ("import runpy, signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
                          "runpy.run_module('beamdrop_jax.cli', run_name='__main__', alter_sys=True)")
    proc = subprocess.Popen([sys.executable, "-c", as_from_a_terminal, *argv], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, cwd=tmp_path, env={**os.environ, **(env or {})})
    chunks = []
    reader = threading.Thread(target=lambda: chunks.extend(iter(lambda: os.read(proc.stderr.fileno(), 4096), b"")))
    reader.start()
    deadline = time.monotonic() + 300
    while marker not in b"".join(chunks) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, b"".join(chunks).decode()[-2000:]
    time.sleep(after_s)
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    code = proc.wait(timeout=120)
    elapsed = time.monotonic() - sent
    reader.join()
    return code, b"".join(chunks).decode(), elapsed


def _visible_lines(stderr):
    """What a terminal shows of stderr: progress bars (redrawn after \\r, cleared at their end) and the note on
    compiling left out."""
    lines = [line.rsplit("\r", 1)[-1].strip() for line in stderr.split("\n")]
    return [line for line in lines if line and not line.startswith("beamdrop: compiling") and "it/s]" not in line
            and "rows/s]" not in line]


def test_ctrl_c_while_the_csv_is_written_is_one_line_exit_130_and_no_csv(tmp_path):
    out = tmp_path / "out"
    code, err, _ = _interrupt(tmp_path, ["montecarlo", "-n", "2000000", "--contact-model", "rigid",
                                         "--allowable-microstrain", "2000", "--out",
                                         str(out), "--no-plots"],
                              b"writing montecarlo-drops.csv", after_s=0.5)
    assert code == 130, err[-2000:]
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-3000:]
    assert _visible_lines(err) == ["beamdrop montecarlo: interrupted; no results written"], err[-2000:]
    assert _leftovers(out) == []  # neither montecarlo-drops.csv nor its temporary file


def test_ctrl_c_while_compiling_ends_the_command_at_once(tmp_path):
    """An XLA compile holds the main thread for seconds (this command about 25 s in all on 2 cores, 3 of them
    importing): the interrupt ends the command within a second or two all the same."""
    env = {"BEAMDROP_NO_CACHE": "1", "JAX_COMPILATION_CACHE_DIR": ""}
    code, err, elapsed = _interrupt(tmp_path, ["montecarlo", "-n", "1000", "--allowable-microstrain", "2000",
                                               "--no-plots", "--seed", "7"], b"compiling",
                                    after_s=6.0, env=env)
    assert code == 130, err[-2000:]
    assert "Traceback" not in err, err[-3000:]
    assert _visible_lines(err) == ["beamdrop montecarlo: interrupted; no results written"], err[-2000:]
    assert elapsed < 5.0


def test_an_interrupt_lost_in_a_garbage_collection_callback_is_delivered_again():
    """Ctrl-C can land in JAX's garbage-collection callback, whose exceptions Python prints as 'Exception ignored'
    with a traceback (seen once in CI); the command's hook delivers it again to the command's own code."""
    import signal
    import time
    import types

    from beamdrop_jax import cli

    printed = []
    hook = cli._redeliver_lost_interrupts(printed.append)
    previous = signal.getsignal(signal.SIGINT)
    try:
        with pytest.raises(KeyboardInterrupt):
            hook(types.SimpleNamespace(exc_type=KeyboardInterrupt, exc_value=KeyboardInterrupt()))
            time.sleep(5.0)  # the interrupt comes back within milliseconds
    finally:
        signal.signal(signal.SIGINT, previous)
    assert printed == []
    other = types.SimpleNamespace(exc_type=ValueError, exc_value=ValueError("x"))
    hook(other)
    assert printed == [other]  # anything else is printed as before


def test_ctrl_c_after_some_files_names_the_complete_ones(tmp_path, monkeypatch, capsys):
    import matplotlib.figure

    real, calls = matplotlib.figure.Figure.savefig, []

    def interrupted_in_the_second(self, fname, *args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            fname.write(b"\x89PNG\r\n\x1a\n")
            raise KeyboardInterrupt
        return real(self, fname, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", interrupted_in_the_second)
    assert main(["drop", "--out", str(tmp_path)]) == 130
    captured = capsys.readouterr()
    assert _visible_lines(captured.err) == [f"beamdrop drop: interrupted; kept the complete files "
                                            f"{tmp_path / 'scene.png'}, nothing else written"]
    assert _leftovers(tmp_path) == ["scene.png"]


def test_an_impossible_n_is_refused_at_once(tmp_path):
    """-n 10^12 drops (120 TB of results) once ran into XLA and aborted there 20 s later."""
    import time

    start = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "beamdrop_jax.cli", "montecarlo", "-n", "1000000000000",
                           "--allowable-microstrain", "2000", "--no-plots", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=300)
    elapsed = time.monotonic() - start
    assert done.returncode == 2, done.stderr[-2000:]
    assert len(done.stderr.strip().splitlines()) == 1 and "-n 1000000000000 needs about 120 TB of memory" in done.stderr
    assert elapsed < 10, elapsed  # importing: no compile, no run
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------------------------
# Issue 39, part 2: answers that mislead, figures that hide or contradict.


def _line(out, label):
    return next(line for line in out.splitlines() if line.strip().startswith(label))


def test_flat_plate_drop_prints_plain_numbers_and_names_the_cli_option(capsys, tmp_path):
    assert main(["drop", "--scene", "jesd22-board", "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "flat onto face 3 (bottom, -e2)" in out and "onto a corner" not in out
    assert _line(out, "peak stress y (mm)").split()[-1] == "0"  # on the centre line, not -1.5e-08
    assert _line(out, "gauge peak strain (microstrain)").split()[-1] == "3424.92"  # not "(3424.92)"
    # The 12 x 12 Ritz basis is the largest error on four screws (0.5 % at the centre against 24 x 24), and the
    # note names where a command-line user sets it.
    note = _line(out, "note: not converged")
    assert "raise Plate.basis (now (12, 12); --basis NX,NY, or `basis = [nx, ny]` in the scene file's [plate]" in note
    # --basis sets it: the same answer as the plate built with that basis.
    import dataclasses

    import equinox as eqx
    import beamdrop_jax as bd

    assert main(["drop", "--scene", "jesd22-board", "--basis", "14,16", "--no-plots", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    board = bd.load_scene("jesd22-board")
    finer = eqx.tree_at(lambda s: s.board, board, dataclasses.replace(board.board, basis=(14, 16)))
    with _through_the_programs_drop_kept():
        expected = float(bd.simulate(finer).peak.strain) * 1e6
    np.testing.assert_allclose(report["peak_strain_microstrain"], expected, rtol=1e-9)  # as --json rounds it
    assert main(["drop", "--basis", "14,16", "--no-plots"]) == 2  # a beam has no basis
    assert "sets a plate's Ritz basis; this scene's board is a beam" in capsys.readouterr().err
    # A plate supported along its long sides needs more modes (its modes across the width, coupled by Poisson's
    # ratio): the note names the option.
    scene = tmp_path / "sfsf.toml"
    scene.write_text('extends = "jedec"\n[plate]\nlength = 0.1\nwidth = 0.05\nthickness = 1e-3\n'
                     'youngs_modulus = 22e9\ndensity = 1900.0\npoisson_ratio = 0.3\nedges = "SFSF"\n')
    assert main(["drop", "--scene", str(scene), "--no-plots", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["converged"] is False and report["n_modes"] == 16
    assert any("raise --max-modes (Numerics.max_modes, 16 here" in note for note in report["notes"]), report["notes"]
    assert isinstance(report["peak_stress_MPa"], float)  # --json keeps its types


def test_flat_landing_figures_show_the_impulse_used_and_both_corners():
    import matplotlib

    matplotlib.use("Agg")
    import beamdrop_jax as bd

    scene = bd.load_scene("jesd22-board")
    # The strain map's test's drop (with its gauge): the two share a compiled program.
    res = bd.simulate(scene, bd.Numerics(n_modes=4), gauges=[(0.066, 0.0)])
    P = np.asarray(res.impulse.P)
    fig = bd.plot_impacts(scene, res)
    ax = fig.axes[0]
    assert "Flat landing on face 3" in ax.get_title() and f"{P[1]:.4g}" in ax.get_title()
    star = next(line for line in ax.lines if line.get_label().startswith("final impulse"))
    np.testing.assert_allclose([star.get_xdata()[0], star.get_ydata()[0]], P, rtol=1e-12)
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(text.startswith("final impulse") for text in labels)

    fig = bd.plot_scene(scene, res)
    ax = fig.axes[0]
    face = next(line for line in ax.lines if line.get_label().startswith("face 3 strikes flat"))
    np.testing.assert_allclose(face.get_ydata(), [0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(np.ptp(face.get_xdata()), 132.0, rtol=1e-9)  # both corners, the whole face
    assert "1.12 m" in ax.get_title() and "1.11782" not in ax.get_title()
    assert "not to scale" in ax.get_legend().get_title().get_text()
    red = [t for t in ax.texts if "impulse" in t.get_text()]
    assert len(red) == 1 and "4.68" in red[0].get_text()
    # The drawing fills the figure: its axes take most of the figure's height (no wide empty margins).
    fig.canvas.draw()
    assert ax.get_position().height > 0.45
    impact_default = bd.plot_impacts(bd.Scene.default(), bd.simulate(bd.Scene.default(), bd.Numerics(n_modes=4)))
    legend = impact_default.axes[0].get_legend()
    impact_default.canvas.draw()
    box = legend.get_window_extent()
    axes_box = impact_default.axes[0].get_window_extent()
    assert box.y1 < axes_box.y0  # below the axes: it covers no line (the C = 0 line ran under it)
    assert "final impulse P" in [t.get_text() for t in legend.get_texts()]


def test_campaign_says_why_drops_are_zero_and_judges_a_limit(tmp_path, capsys):
    argv = ["campaign", "--standard", "ista-1a", "--n-modes", "4", "--no-plots", "--out", str(tmp_path)]
    assert main(argv + ["--allowable-microstrain", "3000"]) == 0
    out = capsys.readouterr().out
    for label in ("face 2", "face 4", "edge 2-5"):
        row = next(line for line in out.splitlines() if line.split()[1:3] == label.split())
        assert "0.00" in row and "no bending in the plane model" in row and row.split()[9] == "n/a", row
    assert "FAIL: 3 of 5 drops judged exceed 3000 microstrain" in out
    assert main(argv) == 0  # without a limit: no verdicts, the zero rows still say why
    out = capsys.readouterr().out
    assert "judged" not in out and out.count("no bending in the plane model") >= 3


def test_campaign_chart_explains_zero_and_na_bars_and_draws_the_limit():
    import matplotlib

    matplotlib.use("Agg")
    import beamdrop_jax as bd

    numerics = bd.Numerics(n_modes=4)
    result = bd.campaign(bd.Scene.default(), "ista-1a", numerics)
    assert result.unbent == [3, 5, 7]  # edge 2-5, faces 2 and 4
    fig = bd.plot_campaign(result, scene="default", limit=3000e-6, quantity="strain")
    ax = fig.axes[0]
    texts = {int(round(t.get_position()[0])): t for t in ax.texts if t.get_text().startswith(("0:", "n/a"))}
    assert {i: t.get_text() for i, t in texts.items()} == {3: "0: no bending", 5: "0: no bending",
                                                            7: "0: no bending", 8: "n/a: out of the plane",
                                                            9: "n/a: out of the plane"}
    for t in texts.values():  # readable: not tiny grey
        assert t.get_fontsize() >= 8 and matplotlib.colors.to_rgb(t.get_color())[0] < 0.3
    footnote = " ".join(t.get_text() for t in fig.texts)
    assert "plane model does not bend" in footnote and "n/a" in footnote
    limit = next(line for line in ax.lines if line.get_label().startswith("limit 3000 microstrain"))
    assert list(limit.get_ydata()) == [3000.0, 3000.0] and "3 of 5 drops judged are over (FAIL)" in limit.get_label()
    assert [i for i, bar in enumerate(ax.patches[:10]) if bar.get_hatch()] == [2, 4, 6]

    jesd = bd.plot_campaign(bd.campaign(bd.Scene.default(), "jesd22-b111", numerics)).axes[0]
    assert "30 drops" in jesd.get_title() and "1 drop" not in jesd.get_title()
    assert jesd.get_xticklabels()[0].get_text() == "board-level half-sine\n1500 g 0.5 ms"  # whole, not "[...]"
    mil = bd.plot_campaign(bd.campaign(bd.Scene.default(), "mil-std-810h-516-iv", numerics), scene="default")
    assert mil.axes[0].get_title().split("\n") == [
        "MIL-STD-810H Method 516.8 Procedure IV transit drop, materiel under 45.4 kg",
        "26 drops from 1.22 m, scene default"]


def test_optimize_keeps_the_board_in_a_region_and_says_what_the_objective_leaves_out(tmp_path, capsys):
    assert main(["optimize", "--orientations", "30,60", "--steps", "3", "--starts", "2", "--n-modes", "4",
                 "--region", "-10,-5,10,5", "--max-angle", "5", "--no-plots", "--json", "--out", str(tmp_path)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["region_centre_box_mm"] == [[-10.0, -5.0], [10.0, 5.0]] and report["max_angle_deg"] == 5.0
    c1, c2 = report["after_centre_mm"]
    assert -10 <= c1 <= 10 and -5 <= c2 <= 5 and abs(report["after_angle_deg"]) <= 5
    assert report["objective_leaves_out"].startswith("motion along the board and out of the plane")
    assert report["notes"][0].startswith("the objective leaves out motion along the board and out of the plane")
    assert report["largest_jump_along_the_board_after_m_per_s"] > 1.0  # the motion it leaves out is not small
    history = np.genfromtxt(tmp_path / "optimize-history.csv", delimiter=",", names=True)
    assert np.all(np.abs(history["c1_mm"]) <= 10) and np.all(np.abs(history["c2_mm"]) <= 5)
    assert np.all(np.abs(history["angle_deg"]) <= 5 + 1e-9)


def test_montecarlo_varies_heights_orientations_and_durations_and_says_so(tmp_path, capsys):
    assert main(["montecarlo", "-n", "2000", "--n-modes", "4", "--contact-model", "rigid", "--allowable-microstrain",
                 "2500", "--orientations",
                 "10:80", "--heights", "0.5:1.5", "--durations", "0.2:1", "--no-plots", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert ("2000 random drops (orientation uniform on [10, 80] deg; height uniform on [0.5, 1.5] m; contact duration "
            "uniform on [0.2, 1] ms; every other field as in the scene)") in out
    table = np.genfromtxt(tmp_path / "montecarlo-drops.csv", delimiter=",", names=True, dtype=None, encoding=None)
    for name, lo, hi in (("orientation_deg", 10, 80), ("height_m", 0.5, 1.5), ("contact_duration_ms", 0.2, 1.0)):
        assert lo <= table[name].min() and table[name].max() <= hi and np.ptp(table[name]) > 0.8 * (hi - lo), name
    assert main(["montecarlo", "-n", "200", "--n-modes", "4", "--allowable-microstrain", "2500", "--orientations",
                 "30", "--heights", "1:2", "--no-plots", "--json", "--out", str(tmp_path)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["varied"] == ("height uniform on [1, 2] m; orientation fixed at 30 deg; every other field as in "
                                "the scene")


def test_montecarlo_face_bias_and_the_rigid_flat_landing_it_cannot_draw(tmp_path, capsys):
    import beamdrop_jax as bd

    assert main(["montecarlo", "-n", "400", "--n-modes", "4", "--contact-model", "rigid", "--allowable-microstrain",
                 "2500", "--face-bias", "0.5:1", "--no-plots", "--json", "--out", str(tmp_path)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["varied"].startswith("orientation: 0.5 of the drops near a face (0, 90, 180, 270 deg plus a normal "
                                       "deviation of 1 deg)")
    table = np.genfromtxt(tmp_path / "montecarlo-drops.csv", delimiter=",", names=True, dtype=None, encoding=None)
    off = np.abs(np.angle(np.exp(4j * np.radians(table["orientation_deg"])))) / 4
    assert 0.45 < np.mean(off < np.radians(4)) < 0.62  # 0.5 near a face + 0.5 * 32/360 by chance
    # Drawn drops near a face strike one corner first under the rigid law; the exact flat landing is reported apart.
    scene = bd.Scene.default().replace(**{"contact.model": "rigid", "drop.orientation": 0.0})
    assert scene.contact.model == "rigid"
    with pytest.raises(ValueError, match="Contact.model = 'rigd' \\(did you mean 'rigid'\\?\\)"):
        scene.replace(**{"contact.model": "rigd"})
    flat = bd.simulate(scene)
    np.testing.assert_allclose(report["flat_landing_peak_strain_microstrain"], float(flat.peak.strain) * 1e6,
                               rtol=1e-9)
    assert report["flat_landing_peak_strain_microstrain"] > 1.5 * report["peak_strain_max_microstrain"]
    assert any(note.startswith("a drop exactly on a face gives up to") for note in report["notes"])


def test_montecarlo_figure_keeps_radial_labels_off_the_curve_and_draws_the_limit():
    import jax
    import matplotlib

    matplotlib.use("Agg")
    import beamdrop_jax as bd

    scene, key = bd.Scene.default(), jax.random.PRNGKey(0)
    scene = type(scene)(scene.housing, scene.board, scene.placement, scene.drop, scene.contact.with_model("rigid"))
    res = bd.montecarlo(scene, 20000, key, numerics=bd.Numerics(n_modes=4), progress=False)
    fig = bd.plot_montecarlo(res, limit=2000e-6, quantity="strain", varied="orientation uniform on [0, 360] deg")
    polar = fig.axes[0]
    assert len(fig.axes) == 2  # no colour bar repeating the radius when only the orientation varies
    assert "orientation uniform on [0, 360] deg" in fig.get_suptitle()
    circle = next(line for line in polar.lines if line.get_label() == "limit 2000 microstrain")
    np.testing.assert_allclose(circle.get_ydata(), 2000.0)
    assert np.ptp(circle.get_xdata()) >= 2 * np.pi - 1e-9  # the whole circle
    fig.canvas.draw()
    points = polar.transData.transform(np.c_[np.asarray(res.samples.drop.orientation),
                                             np.asarray(res.peak_strain) * 1e6])
    labels = [t for t in polar.get_yticklabels() if t.get_text()]
    assert len(labels) >= 2
    for label in labels:
        box = label.get_window_extent().padded(2)
        inside = ((box.x0 <= points[:, 0]) & (points[:, 0] <= box.x1) & (box.y0 <= points[:, 1])
                  & (points[:, 1] <= box.y1))
        assert not np.any(inside), label.get_text()
    # With the height varied too, the colour shows the height (not the radius again).
    spread = bd.DropDistribution(height=("uniform", 0.5, 1.5))
    res = bd.montecarlo(scene, 4000, key, spread, numerics=bd.Numerics(n_modes=4), progress=False)
    fig = bd.plot_montecarlo(res, limit=2000e-6, quantity="strain", distribution=spread)
    assert fig.axes[-1].get_ylabel() == "drop height (m)"
    assert "height uniform on [0.5, 1.5] m" in fig.get_suptitle()


def test_strain_map_shows_the_gauge_on_the_peak_and_no_tabs_round_the_mounts():
    import matplotlib

    matplotlib.use("Agg")
    import beamdrop_jax as bd

    scene, numerics = bd.load_scene("jesd22-board"), bd.Numerics(n_modes=4)
    res = bd.simulate(scene, numerics, gauges=[(0.066, 0.0)])
    strain_map = bd.plate_strain_map(scene, res, numerics)
    assert np.isnan(np.asarray(strain_map.strain)).any()  # the mount discs: no value there
    fig = bd.plot_plate_strain(strain_map, res, scene.board)
    ax = fig.axes[0]
    shaded = ax.collections[0].get_array()
    assert np.all(np.isfinite(np.ma.filled(shaded, np.nan)))  # NaN cells drew white square tabs past the discs
    star = next(line for line in ax.lines if line.get_label().startswith("peak"))
    gauge = next(line for line in ax.lines if line.get_label().startswith("gauges"))
    assert gauge.get_zorder() > star.get_zorder() and gauge.get_markersize() > star.get_markersize()
    assert gauge.get_markerfacecolor() == "none"  # an open square round the star, drawn over it
    assert [t.get_text() for t in ax.texts] == ["1"]


def test_a_plates_strain_peak_has_its_own_place_and_the_map_marks_it():
    """Poisson's ratio couples a plate's two directions: on the JESD22 board with nu = 0.3 the largest principal
    strain is on a free edge (uniaxial stress there) and the largest principal stress on the centre line. The
    strain map is drawn at the strain peak's time, and its star sits where the map, the field on a plain 1 mm grid,
    is largest and reads the same value (the star was at the stress peak, labelled with the strain)."""
    import matplotlib

    matplotlib.use("Agg")
    import beamdrop_jax as bd

    scene = bd.load_scene("jesd22-board").replace(**{"board.poisson_ratio": 0.3})
    res = bd.simulate(scene)
    p = res.peak
    assert abs(float(p.y)) < 1e-6 and abs(float(p.strain_y)) == pytest.approx(0.0385, abs=1e-9)
    strain_map = bd.plate_strain_map(scene, res)
    assert float(strain_map.t) == float(p.strain_t)
    field, x, y = (np.asarray(v) for v in (strain_map.strain, strain_map.x, strain_map.y))
    # The grid point at the reported place (the board is symmetric: its mirror image across the centre line ties).
    i, j = np.argmin(np.abs(x - float(p.strain_x))), np.argmin(np.abs(y - float(p.strain_y)))
    assert (x[i], y[j]) == pytest.approx((float(p.strain_x), float(p.strain_y)), abs=1e-7)
    assert field[i, j] == pytest.approx(np.nanmax(field), rel=1e-12)
    assert field[i, j] == pytest.approx(float(p.strain), rel=1e-6)  # two programs: round-off apart
    assert field[i, j] > field[i, np.argmin(np.abs(y))] * 1.01  # not on the centre line, where the stress peaks
    ax = bd.plot_plate_strain(strain_map, res, scene.board).axes[0]
    star = next(line for line in ax.lines if line.get_label().startswith("peak"))
    assert (star.get_xdata()[0], star.get_ydata()[0]) == pytest.approx((float(p.strain_x) * 1e3, float(p.strain_y) * 1e3))
    assert res.summary()["peak_strain_y_mm"] == pytest.approx(float(p.strain_y) * 1e3)


def test_gauge_and_sensitivity_draw_figures_and_latency_writes_nothing(tmp_path, monkeypatch, capsys):
    import matplotlib

    matplotlib.use("Agg")
    import beamdrop_jax as bd
    from beamdrop_jax import _bench

    assert main(["drop", "--gauge", "30", "--n-modes", "4", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "gauge_30mm.png").stat().st_size > 10_000
    assert main(["sensitivity", "--n-modes", "4", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "sensitivity-stress.png").stat().st_size > 10_000
    capsys.readouterr()
    rows = bd.sensitivities(bd.Scene.default(), bd.Numerics(n_modes=4))
    ax = bd.plot_sensitivity(rows).axes[0]
    drawn = {t.get_text(): p.get_width() for t, p in zip(ax.get_yticklabels(), ax.patches)}
    expected = {r.field: r.elasticity for r in rows if r.elasticity is not None and abs(r.elasticity) >= 1e-9}
    assert drawn.keys() == expected.keys() and all(drawn[k] == pytest.approx(expected[k]) for k in drawn)
    assert ax.get_yticklabels()[-1].get_text() == max(expected, key=lambda k: abs(expected[k]))  # the largest on top
    assert "placement.centre[0]" in " ".join(t.get_text() for t in ax.texts)  # no elasticity: named, not drawn

    monkeypatch.setattr(_bench, "latency_bench", lambda repeats: {"import_s": 1.0, "first_drop_s": 2.0})
    out = tmp_path / "latency"
    assert main(["bench", "--latency", "--repeats", "1", "--out", str(out)]) == 0
    assert "first drop" in capsys.readouterr().out and not out.exists()  # printed only: no empty folder


def test_a_plate_gauge_anywhere_from_the_command_line(tmp_path, capsys):
    """`--gauge X,Y` reads a gauge anywhere on a plate (mm from end A, and across from the centre line), the same
    reading as `bd.simulate(..., gauges=...)`; a gauge the board cannot read is refused in one line."""
    import beamdrop_jax as bd

    argv = ["drop", "--scene", "jesd22-board", "--gauge", "30,20", "--no-plots", "--json", "--out", str(tmp_path)]
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    assert [(g["x_mm"], g["y_mm"]) for g in report["gauges"]] == [(66.0, 0.0), (30.0, 20.0)]
    with _through_the_programs_drop_kept():
        res = bd.simulate(bd.load_scene("jesd22-board"), gauges=((0.066, 0.0), (0.03, 0.02)))
    np.testing.assert_allclose([g["peak_strain_microstrain"] for g in report["gauges"]],
                               np.asarray(res.gauges.peak_strain) * 1e6, rtol=1e-12)
    # Gauges the board cannot read are refused in one line, before any word on compiling: a Y on a beam, a point
    # off the plate or inside a screw's disc (6, 32.5 mm is a screw's centre), and the gauge an optimiser of the
    # screws would minimise.
    for argv, why in ((["drop", "--gauge", "30,20"], "a beam's gauge is X_MM alone"),
                      (["drop", "--scene", "jesd22-board", "--gauge", "66,100"], "is off the plate"),
                      (["drop", "--scene", "jesd22-board", "--gauge", "6,32.5"], "inside a mount's disc"),
                      (["optimize", "--mounts", "--scene", "jesd22-board", "--gauge", "1000,0"],
                       "off the board: valid [0, 132]")):
        assert main(argv + ["--no-plots", "--out", str(tmp_path)]) == 2
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1 and why in err[0], err


def test_optimize_moves_a_plates_screws_from_the_command_line(tmp_path, capsys):
    """`beamdrop optimize --mounts` runs bd.optimize_mounts: the before/after strain of the returned layout, where
    the screws went, whether it converged; options that place the board are refused with it in one line."""
    # Without --orientations the screws are placed for the scene's own drop, as bd.optimize_mounts does.
    argv = ["optimize", "--mounts", "--scene", "jesd22-board", "--steps", "2", "--starts", "1",
            "--n-modes", "4", "--min-spacing", "20", "--no-plots", "--json", "--out", str(tmp_path)]
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["objective"] == "mean peak strain over 1 drop" and len(report["mounts_mm"]) == 4
    assert report["after_microstrain"] <= report["before_microstrain"] * (1 + 1e-9)
    assert report["min_spacing_met"] is True and report["smallest_spacing_mm"] >= 20
    assert (tmp_path / "optimize-mounts-history.csv").exists()
    assert main(["optimize", "--mounts", "--region", "-10,-5,10,5", "--scene", "jesd22-board",
                 "--out", str(tmp_path)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if "compiling" not in line]
    assert len(err) == 1 and "--region and --max-angle place the board" in err[0], err
    assert main(["optimize", "--mounts", "--out", str(tmp_path)]) == 2
    assert "has no plate with mounts" in capsys.readouterr().err
