"""The `beamdrop` command runs each job end to end and writes its files (smoke tests; numbers are tested
elsewhere)."""

import json
import os
import subprocess
import sys

import pytest

from beamdrop_jax.cli import main


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
    assert main(["montecarlo", "-n", "300", "--n-modes", "4", "--out", str(tmp_path)]) == 0
    assert "probability over limit" in capsys.readouterr().out
    assert (tmp_path / "montecarlo.png").exists()
    assert main(["optimize", "--orientations", "30,60", "--steps", "3", "--starts", "1", "--n-modes", "4",
                 "--out", str(tmp_path)]) == 0
    assert "after objective (MPa)" in capsys.readouterr().out
    assert (tmp_path / "placement.png").exists()


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
    assert main(["montecarlo", "-n", "64", "--max-impacts", "2", "--no-plots"]) == 0
    assert "64 random drops" in capsys.readouterr().out


def test_cli_compiles_with_a_flag_jaxlib_knows_and_respects_the_users(monkeypatch):
    from beamdrop_jax import cli

    env = {}
    cli._compile_faster(env)
    assert env == {"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=false"}
    # The flag is real: a JAX process started with it computes (an unknown flag would abort it).
    done = subprocess.run([sys.executable, "-c", "import jax.numpy as jnp; print(float(jnp.ones(3).sum()))"],
                          env={**os.environ, **env}, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "3.0", done.stderr[-500:]
    mine = {"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true --xla_dump_to=/tmp/x"}
    cli._compile_faster(mine)
    assert mine == {"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true --xla_dump_to=/tmp/x"}
    # A flag the installed jaxlib does not name is never passed.
    monkeypatch.setattr(cli, "_FAST_COMPILE_FLAG", "--xla_cpu_no_such_flag_for_beamdrop=false")
    env = {"XLA_FLAGS": "--xla_dump_to=/tmp/x"}
    cli._compile_faster(env)
    assert env == {"XLA_FLAGS": "--xla_dump_to=/tmp/x"}
