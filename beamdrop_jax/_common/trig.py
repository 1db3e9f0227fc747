"""Sine and cosine as plain polynomial arithmetic, for the per-drop hot paths.

XLA on CPU evaluates `sin` and `cos` element by element through a scalar library call (about 10 ns each in float64
on the 2-core development machine, measured), and its fusion pass recomputes a shared `sin` inside every fused loop
that reads it. Written as a Cody-Waite reduction and the Cephes minimax polynomials, the pair vectorises and fuses
like any multiply-add: about 2 ns for both, within 1 ulp of `numpy.sin`/`numpy.cos` for |x| < 2^29 in float64 (the
reduction's exact range; tests/test_trig.py), within 2e-7 for |x| < 100 in float32. Beyond, the reduction loses
digits: wrap such angles first. Subnormal inputs are flushed to zero, as XLA on CPU does everywhere.
"""

import math

import jax
import jax.numpy as jnp

from .compile import is_quick

# Cephes sin.c: minimax polynomials on [-pi/4, pi/4] and pi/4 split so that j * _PI4[0] is exact for j < 2^29.
_SIN = (1.58962301576546568060e-10, -2.50507477628578072866e-8, 2.75573136213857245213e-6,
        -1.98412698295895385996e-4, 8.33333333332211858878e-3, -1.66666666666666307295e-1)
_COS = (-1.13585365213876817300e-11, 2.08757008419747316778e-9, -2.75573141792967388112e-7,
        2.48015872888517045348e-5, -1.38888888888730564116e-3, 4.16666666666665929218e-2)
_PI4 = (7.85398125648498535156e-1, 3.77489470793079817668e-8, 2.69515142907905952645e-15)
_PI4_F32 = (0.78515625, 2.4187564849853515625e-4, 3.77489497744594108e-8)  # Cephes sinf.c: exact in float32


def _horner(coeffs, z):
    out = jnp.full_like(z, coeffs[0])
    for c in coeffs[1:]:
        out = out * z + c
    return out


def sincos(x):
    """(sin x, cos x) elementwise, for real floating x. In programs compiled for latency
    (`_compile.quick_programs`) XLA's own `sin` and `cos`, which make a smaller program."""
    if is_quick():
        return jnp.sin(x), jnp.cos(x)
    return _sincos_cached(x)


@jax.custom_jvp
def _sincos(x):
    x = jnp.asarray(x)
    j = jnp.round(x * (2 / math.pi))  # x = j pi/2 + r with |r| <= pi/4
    r = x
    for part in _PI4_F32 if x.dtype == jnp.float32 else _PI4:
        r = r - j * (2 * part)
    z = r * r
    s = r + r * z * _horner(_SIN, z)
    c = 1.0 - 0.5 * z + z * z * _horner(_COS, z)
    quadrant = j.astype(jnp.int32) & 3  # two's complement: also right for negative j
    sin = jnp.where(quadrant == 0, s, jnp.where(quadrant == 1, c, jnp.where(quadrant == 2, -s, -c)))
    cos = jnp.where(quadrant == 0, c, jnp.where(quadrant == 1, -s, jnp.where(quadrant == 2, -c, s)))
    return sin, cos


@_sincos.defjvp
def _sincos_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    s, c = _sincos(x)
    return (s, c), (c * dx, -s * dx)


# Traced once per argument shape and inlined: a drop's program calls it 30 to 40 times, and tracing its custom JVP
# afresh each time took a tenth of the time to trace a drop (lowering all four of the bench's cold programs 4-7 %
# faster).
_sincos_cached = jax.jit(_sincos, inline=True)


def cexp(z):
    """exp(z) for complex z, through `sincos` (XLA's complex exp calls the scalar sine and cosine)."""
    z = jnp.asarray(z)
    s, c = sincos(jnp.imag(z))
    return jnp.exp(jnp.real(z)) * jax.lax.complex(c, s)
