"""Clattering: after each impact the housing flies freely under gravity until a corner strikes again.

Free flight is closed form: G falls with gravity and the housing turns at constant spin w. Corner q = (q1, q2) (body
coordinates from G) is at height

    h(s) = y_G + v_y s - g s^2 / 2 + q1 sin(theta + w s) + q2 cos(theta + w s)

s seconds after an impact, and |h''| <= M = g + w^2 R (R: half the housing's diagonal). So
h(s + d) >= h(s) + h'(s) d - M d^2 / 2, and stepping to the first zero of that lower bound never passes a root
(conservative advancement): it closes quadratically on a root where the corner approaches and steps over a near
miss. The earliest root over the four corners is the next impact. A final Newton step whose slope is held
constant gives the impact time the implicit-function derivative ds/dp = -(dh/dp) / h'.

The sequence stops at `max_impacts`, or when the next approach speed is below `rest_speed`. Stopping while the
housing still turns (|w| R >= rest_speed) means a corner stays on the ground and the housing pivots about it (for
example restitution 0, or a corner chattering to rest): free flight does not describe what follows, so the
sequence is flagged `Flag.PIVOTING_CONTACT` instead of continued with a wrong answer. Rocking between two corners
can also converge onto a face, ending in two corners landing at once while the housing still turns:
`Flag.FLAT_LANDING_WITH_MOTION`, outside the single-contact law as for a first impact.
"""

import enum

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .._common.checks import GRAVITY, Flag, combine, flag_if
from .kinematics import HousingImpact, corner_impact, housing_impact, support_jumps
from .._scene.containers import Scene
from .._common.trig import sincos


class Ending(enum.IntEnum):
    """Why an impact sequence ended: `MAX_IMPACTS` reached, the housing came to `AT_REST` (next approach speed
    below `rest_speed`, no turning), a corner stayed on the ground while the housing turned (`PIVOT`), or the
    search for the next impact gave up (`SEARCH_GAVE_UP`: its conservative steps shrink as 1 / spin^2, and a
    housing spinning at 1e4 rad/s or more needs more than `MAX_ADVANCES` of them)."""

    MAX_IMPACTS = 0
    AT_REST = 1
    PIVOT = 2
    SEARCH_GAVE_UP = 3


class Impacts(eqx.Module):
    """The impacts of one drop, in time order (arrays of length K = `max_impacts`; entries past `count` are
    padding: `applied` False, `P` and `support_jumps` zero, `t` the last impact's time).

    - `t`: time of each impact from the first, s. `orientation`: the housing's angle then, rad.
    - `corner`: the striking corner's body coordinates from G, m.
    - `P`: impulse (Pt, Pn), N s. `energy_change`: the impact's kinetic energy change, J. `approach_speed`: the corner's normal speed towards the ground, m/s (for the
      first padding entry: the approach that ended the sequence). `mode`: the Routh `ImpactMode`.
    - `support_jumps`: the board supports' normal velocity jumps (dvA, dvB), m/s.
    - `count`: impacts applied. `ending`: an `Ending`. `flags`: `Flag` mask of the sequence.
    """

    t: Float[Array, " K"]
    orientation: Float[Array, " K"]
    corner: Float[Array, "K 2"]
    P: Float[Array, "K 2"]
    energy_change: Float[Array, " K"]
    approach_speed: Float[Array, " K"]
    mode: Int[Array, " K"]
    support_jumps: Float[Array, "K 2"]
    applied: Bool[Array, " K"]
    count: Int[Array, ""]
    ending: Int[Array, ""]
    flags: Int[Array, ""]

    @property
    def pivot(self) -> Bool[Array, ""]:
        return self.ending == Ending.PIVOT


def _corners(width, height) -> Float[Array, "4 2"]:
    w, h = width / 2, height / 2
    return jnp.stack([jnp.stack([w, h]), jnp.stack([-w, h]), jnp.stack([-w, -h]), jnp.stack([w, -h])])


def corner_heights(q, y, vy, theta, spin, s):
    """Height above the ground (m) and its rate (m/s) of body points `q` (..., 2) at time `s` of free flight
    from centre-of-mass height `y`, vertical velocity `vy`, angle `theta` and `spin`."""
    angle = theta + spin * s
    sn, cs = sincos(angle)
    h = y + vy * s - 0.5 * GRAVITY * s**2 + q[..., 0] * sn + q[..., 1] * cs
    dh = vy - GRAVITY * s + spin * (q[..., 0] * cs - q[..., 1] * sn)
    return h, dh


MAX_ADVANCES = 512


def next_contact(width, height, y, vy, theta, spin, skip=None):
    """The next impact of a housing in free flight: `(s, corner_index, found)`, s the time (s) until a corner
    reaches the ground while approaching it (differentiable by the implicit function theorem), `found` False if
    the search failed (then s = 0). `skip`: a boolean mask (4,) of corners left out (the order of `_corners`)."""
    q = _corners(width, height)
    R = 0.5 * jnp.hypot(width, height)
    sg = jax.lax.stop_gradient
    q_, y_, vy_, th_, w_ = sg((q, y, vy, theta, spin))
    M = GRAVITY + w_**2 * R
    # G is at most R above the ground when a corner touches and at least min(W, H)/2: past this time some
    # corner must already have struck.
    drop = jnp.maximum(y_ - 0.5 * jnp.minimum(width, height), 0.0)
    s_max = (vy_ + jnp.sqrt(vy_**2 + 2 * GRAVITY * drop)) / GRAVITY
    scale = sg(R) + jnp.abs(vy_) * s_max + 0.5 * GRAVITY * s_max**2
    tol = 64 * jnp.finfo(scale.dtype).eps * scale
    v_tol = jnp.sqrt(2 * M * tol)

    def advance(carry):
        s, found, done, i = carry
        h, dh = corner_heights(q_, y_, vy_, th_, w_, s)
        root = ~done & (h <= tol) & (dh <= v_tol)
        step = (dh + jnp.sqrt(jnp.maximum(dh**2 + 2 * M * jnp.maximum(h, 0.0), 0.0))) / M
        s_new = jnp.where(done | root, s, s + step)
        found = found | root
        first = jnp.min(jnp.where(found, s_new, jnp.inf))
        done = done | root | (s_new > s_max + tol) | (s_new > first)
        return s_new, found, done, i + 1

    def going(carry):
        _, _, done, i = carry
        return ~jnp.all(done) & (i < MAX_ADVANCES)

    zeros = jnp.zeros(4, dtype=scale.dtype)
    skipped = zeros > 1 if skip is None else jnp.asarray(skip)
    s, found, _, _ = jax.lax.while_loop(going, advance, (zeros, zeros > 1, skipped, 0))
    c = jnp.argmin(jnp.where(found, s, jnp.inf))
    any_found = jnp.any(found)
    s0 = sg(jnp.where(any_found, s[c], 0.0))
    h, dh = corner_heights(q[c], y, vy, theta, spin, s0)
    slope = sg(jnp.where(dh < -v_tol, dh, -1.0))  # an approaching corner; otherwise the impact is not applied
    return s0 - h / slope, c, any_found


class _Flight(eqx.Module):
    t: Array
    y: Array
    v: Array
    theta: Array
    spin: Array
    done: Array
    ending: Array
    failed: Array


def impact_sequence(
    scene: Scene, max_impacts: int = 3, rest_speed: float = 0.02, law: str = "poisson"
) -> tuple[Impacts, HousingImpact]:
    """The drop's impacts: the first corner impact, then free flight and the next impact, up to `max_impacts`,
    stopping early when the next approach speed is below `rest_speed` (m/s). Returns `(impacts, first)` with
    `first` the first impact's `HousingImpact`. A pivot (see the module notes) sets `Flag.PIVOTING_CONTACT`; a
    search that gave up (`Ending.SEARCH_GAVE_UP`) `Flag.SOLVER_FAILED`. Jit-, vmap- and grad-able."""
    if not (isinstance(max_impacts, int) and max_impacts >= 1):
        raise ValueError(f"max_impacts = {max_impacts!r}; valid: an int >= 1")
    if not rest_speed > 0:
        raise ValueError(f"rest_speed = {rest_speed!r}; valid: > 0 m/s")
    first = housing_impact(scene, law=law)
    h = scene.housing
    d = scene.drop
    R = 0.5 * jnp.hypot(h.width, h.height)
    v_before = jnp.stack([d.horizontal_speed, -jnp.sqrt(2.0 * GRAVITY * jnp.maximum(d.height, 0.0))])

    def record(hit: HousingImpact, t, theta, applied):
        jumps = support_jumps(scene, hit, theta)
        return dict(
            t=t,
            orientation=theta,
            corner=hit.corner,
            P=jnp.where(applied, hit.impact.P, 0.0),
            energy_change=jnp.where(applied, hit.impact.energy_change, 0.0),
            approach_speed=-hit.v0[1],
            mode=hit.impact.mode,
            support_jumps=jnp.where(applied, jumps, 0.0),
            applied=applied,
            flags=jnp.where(applied, hit.flags, 0),
        )

    zero = jnp.zeros_like(d.orientation)
    rows = [record(first, zero, d.orientation, jnp.asarray(True))]
    state = _Flight(
        t=zero,
        y=first.r[1],
        v=v_before + first.dv_G,
        theta=d.orientation,
        spin=d.spin + first.dw,
        done=jnp.asarray(False),
        ending=jnp.int32(Ending.MAX_IMPACTS),
        failed=jnp.asarray(False),
    )

    def step(f: _Flight, _):
        s, _, found = next_contact(h.width, h.height, f.y, f.v[1], f.theta, f.spin)
        theta = f.theta + f.spin * s
        v = f.v + jnp.stack([jnp.zeros_like(s), -GRAVITY * s])
        hit = corner_impact(h, scene.contact, theta, v, f.spin, law=law)
        applied = ~f.done & found & (-hit.v0[1] >= rest_speed)
        stopping = ~f.done & ~applied
        turning = jnp.abs(f.spin) * R >= rest_speed
        why = jnp.where(~found, Ending.SEARCH_GAVE_UP, jnp.where(turning, Ending.PIVOT, Ending.AT_REST))
        ending = jnp.where(stopping, why, f.ending).astype(jnp.int32)
        keep = lambda new, old: jnp.where(applied, new, old)  # noqa: E731
        t = keep(f.t + s, f.t)
        out = record(hit, t, keep(theta, f.theta), applied)
        new = _Flight(
            t=t,
            y=keep(hit.r[1], f.y),
            v=keep(v + hit.dv_G, f.v),
            theta=keep(theta, f.theta),
            spin=keep(f.spin + hit.dw, f.spin),
            done=f.done | ~applied,
            ending=ending,
            failed=f.failed | (stopping & ~found),
        )
        return new, out

    if max_impacts > 1:
        state, later = jax.lax.scan(step, state, None, length=max_impacts - 1)
        rows = {k: jnp.concatenate([jnp.asarray(rows[0][k])[None], later[k]]) for k in rows[0]}
    else:
        rows = {k: jnp.asarray(v)[None] for k, v in rows[0].items()}
    flags = combine(
        first.flags,
        jnp.bitwise_or.reduce(rows.pop("flags")),
        flag_if(state.ending == Ending.PIVOT, Flag.PIVOTING_CONTACT),
        flag_if(state.failed, Flag.SOLVER_FAILED),
    )
    impacts = Impacts(**rows, count=jnp.sum(rows["applied"]).astype(jnp.int32), ending=state.ending, flags=flags)
    return impacts, first
