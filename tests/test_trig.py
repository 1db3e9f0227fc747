"""The polynomial sine/cosine against NumPy's libm, its derivative, and the complex exponential built on it."""

import math

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings, strategies as st

from beamdrop_jax._common.trig import cexp, sincos


def test_sincos_matches_libm_to_an_ulp():
    rng = np.random.default_rng(0)
    x = np.concatenate([
        rng.uniform(-7, 7, 100_000),
        rng.uniform(-1e4, 1e4, 100_000),
        rng.uniform(-2.0**29, 2.0**29, 10_000),  # the reduction's exact range
        np.arange(-64, 65) * (math.pi / 4),  # quadrant edges
        [0.0, 1e-300, -1e-9],
    ])
    s, c = (np.asarray(v) for v in sincos(jnp.asarray(x)))
    # One ulp of 1 is 2.2e-16: absolute, since near zeros of sin a relative measure means nothing.
    assert np.max(np.abs(s - np.sin(x))) <= 2.3e-16
    assert np.max(np.abs(c - np.cos(x))) <= 2.3e-16
    small = np.abs(x) < 1e-8
    np.testing.assert_array_equal(s[small], x[small])  # sin x = x exactly there, as libm gives


def test_sincos_float32():
    x = np.random.default_rng(1).uniform(-100, 100, 10_000).astype(np.float32)
    with jax.enable_x64(False):
        s, c = sincos(jnp.asarray(x))
        assert s.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(s), np.sin(x.astype(np.float64)), atol=2e-7)
    np.testing.assert_allclose(np.asarray(c), np.cos(x.astype(np.float64)), atol=2e-7)


def test_sincos_derivatives_are_cos_and_minus_sin():
    x = jnp.linspace(-10, 10, 101)
    ds = jax.vmap(jax.grad(lambda v: sincos(v)[0]))(x)
    dc = jax.vmap(jax.grad(lambda v: sincos(v)[1]))(x)
    np.testing.assert_allclose(ds, np.cos(np.asarray(x)), atol=1e-15)
    np.testing.assert_allclose(dc, -np.sin(np.asarray(x)), atol=1e-15)
    # Second derivative through the custom JVP: d2 sin = -sin.
    d2 = jax.vmap(jax.grad(jax.grad(lambda v: sincos(v)[0])))(x)
    np.testing.assert_allclose(d2, -np.sin(np.asarray(x)), atol=1e-15)


def test_cexp_matches_numpy():
    rng = np.random.default_rng(2)
    z = rng.uniform(-50, 5, 1000) + 1j * rng.uniform(-3000, 3000, 1000)
    np.testing.assert_allclose(np.asarray(cexp(jnp.asarray(z))), np.exp(z), rtol=2e-15, atol=0)


@settings(max_examples=200, deadline=None)
@given(st.floats(min_value=-1e6, max_value=1e6, allow_nan=False))
def test_pythagoras_and_no_nan(x):
    s, c = (float(v) for v in sincos(jnp.asarray(x)))
    assert math.isfinite(s) and math.isfinite(c)
    assert abs(s * s + c * c - 1.0) <= 4.5e-16
