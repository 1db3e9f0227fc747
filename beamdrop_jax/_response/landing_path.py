"""Landings where corners strike together: which contact model a drop takes (`Contact.model`) and the supports'
motion through a compliant landing (DESIGN.md section 7).

**What `"auto"` follows.** The rigid law is exact where the first corner strikes alone: the next strike comes
after the first contact has ended. `"auto"` decides by the rigid law's own prediction of that next strike, `t2`
(free flight after the first strike), against the contact's duration tau:
- `t2 >= (1 + BLEND) tau`: the rigid law, the first strike only, as the thesis did (today's numbers, closed form);
- `t2 <= tau` (the strikes overlap: near-flat landings) or a flat landing: the compliant landing, integrated
  through the board's peak window (one contact duration plus the board's fundamental period) with every strike in
  it, the board driven by the supports' acceleration history;
- in between, the supports' acceleration is the blend `w a_compliant + (1 - w) a_rigid`, `w` a smoothstep in `t2`,
  so that the answer has no jump at the switch.
A contact longer than the board's fundamental period (quasi-static loading; 6.5 ms on the default phone) stays on
the rigid law.
Just outside the overlap the far corner still strikes, a little later; the compliant landing counts that strike,
the first-strike default does not, and the blend carries the answer from one to the other over
tau < t2 < (1 + BLEND) tau (on the default scene from 1.2 to 3.5 deg, in steps under 3 % per 0.05 deg). Following
every strike in the window outside the band too (`Numerics(max_impacts=K)` with the rigid law) changes the answer
there, and everywhere a late strike slaps the board (the default scene at 3 deg: 116 MPa against 55).
`"rigid"` follows the first strike only; `Numerics(max_impacts=K)` follows K rigid strikes whatever the model.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._common.checks import GRAVITY, is_pulse, pulse_duration
from .._impact.clatter import next_contact
from .._common.compile import filter_jit
from .._impact.box import BoxImpact, box_vertices, lowest_vertex
from .._impact.box_landing import BoxLanding, box_landing
from .._impact.kinematics import (HousingImpact, _in_ground, _support_jumps, box_housing_impact, drop_jumps,
                                  housing_impact, plane_drop)
from .._impact.landing import Landing, _landing, housing_corners
from .._impact.motion import HalfSine, LandingMotion
from .._scene.containers import Contact, Scene, board_ends
from .._common.trig import sincos
from .numerics import Numerics
from .pulses import fundamental_period

LANDING_SAMPLES = 1024
"""Samples of the supports' acceleration over the peak window (a 0.5 ms contact in a 7 ms window gets 70)."""

BLEND = 2.0
"""Width of the blend in the next strike's time t2, in contact durations: compliant for t2 <= tau, rigid for
t2 >= (1 + BLEND) tau."""


def landing_window(scene: Scene, numerics: Numerics, modal=None):
    """The board's peak window after the first touch, s: `Numerics.window`, or one contact duration plus the
    board's fundamental period (of `modal`, the board's solved modes, where the caller has them: a plate's
    eigensolve is then not repeated)."""
    if numerics.window is not None:
        return jnp.asarray(numerics.window, dtype=jnp.result_type(float))
    return scene.contact.duration + fundamental_period(scene.board if modal is None else modal)


def next_strike_time(scene: Scene, hit: HousingImpact):
    """When another corner strikes after the rigid law's first strike `hit` (free flight from it), s; inf when
    the search finds none. The struck corner itself is left out: with little restitution it stays at the ground
    (a pivot), which free flight reads as a strike at once."""
    d, h = scene.drop, scene.housing
    v = jnp.stack([d.horizontal_speed, -jnp.sqrt(2.0 * GRAVITY * jnp.maximum(d.height, 0.0))]) + hit.dv_G
    struck = jnp.all(housing_corners(h.width, h.height) == hit.corner, axis=-1)
    s, _, found = next_contact(h.width, h.height, hit.r[1], v[1], d.orientation, d.spin + hit.dw, skip=struck)
    return jnp.where(found, s, jnp.inf)


def compliant_weight(scene: Scene, numerics: Numerics, hit: HousingImpact, modal=None):
    """The compliant landing's share of the supports' motion (0: the rigid law alone, 1: the landing alone), by
    `Contact.model` (module notes). `modal`: the board's solved modes, where the caller has them."""
    model = scene.contact.model
    if model == "rigid":
        return jnp.zeros_like(scene.contact.duration)
    if model == "compliant":
        return jnp.ones_like(scene.contact.duration)
    tau = scene.contact.duration
    w = jnp.where(hit.flat, 1.0, _smoothstep(next_strike_time(scene, hit), tau))
    # A contact longer than the board's fundamental period loads it quasi-statically, and the sampled landing's
    # board solve would need more steps than it is given over such a window: the rigid law's closed form there.
    slow = tau > fundamental_period(scene.board if modal is None else modal)
    if scene.housing.is_box:
        w = box_compliant_weight(scene, numerics, w)
    return jnp.where(is_pulse(tau) & ~slow, w, 0.0)


def compliant_branch(scene: Scene, weight) -> Scene:
    """The scene the compliant path runs on where both paths are traced and the weight picks (`"either"`): `scene`
    where the compliant answer is taken (`weight` > 0), else the same drop with the default contact duration. The
    answer is dropped there, but a duration the landing cannot integrate (an impulse, a 1e-292 s pulse) would make
    its gradient NaN, and NaN times the 0 that the pick gives it is NaN (jax-md's `safe_mask`)."""
    return eqx.tree_at(lambda s: s.contact.duration, scene,
                       jnp.where(weight > 0, scene.contact.duration, Contact().duration))


def _smoothstep(t2, tau):
    # A contact no longer than `IMPULSE_DURATION` counts as 0 long; the stand-in divisor keeps its gradient finite.
    u = jnp.clip(((1.0 + BLEND) * jnp.where(is_pulse(tau), tau, 0.0) - t2) / (BLEND * pulse_duration(tau)), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def box_strike_times(scene: Scene, hit: BoxImpact):
    """When the other vertices of a box strike after the 3D rigid law's first strike `hit`, s (inf: none):
    `(t_edge, t_others)`, the struck vertex's partner along the depth (e3) and the first of the other six. Each
    vertex's height in free flight to second order in time (G's fall, the spin's centripetal term) about the
    first-touch attitude: the times matter where they are short, a few contact durations, where the body has turned
    little."""
    h, d = scene.housing, scene.drop
    v = d.velocity() + hit.dV
    spin = d.angular_velocity() + hit.dOmega
    arms = box_vertices(h.width, h.height, h.depth) @ hit.attitude.T
    height = arms[:, 1] - jnp.min(arms[:, 1])
    rate = v[1] + jnp.cross(spin, arms)[:, 1]
    accel = -GRAVITY + jnp.cross(spin, jnp.cross(spin, arms))[:, 1]
    # The first root of height + rate t + accel t^2 / 2 = 0, in the form that stays finite as accel -> 0.
    disc = rate**2 - 2.0 * accel * height
    real = disc > 0
    den = jnp.where(real, jnp.sqrt(jnp.where(real, disc, 1.0)), 0.0) - rate  # (a gradient-safe square root)
    ok = (den > 0) & (disc >= 0)
    t = jnp.where(ok, 2.0 * height / jnp.where(ok, den, 1.0), jnp.inf)
    struck = lowest_vertex(d.orientation, d.tilt, h.width, h.height, h.depth).index
    partner = jnp.bitwise_xor(struck, 1)  # the other end of its edge along e3
    others = jnp.arange(8)
    return t[partner], jnp.min(jnp.where((others == struck) | (others == partner), jnp.inf, t))


ASYMMETRY = 0.01
"""Where a box's edge along the depth strikes with motion out of the plane, the asymmetry of its two vertices'
strikes (`edge_asymmetry`) up to which the edge still lands as one contact (the plane section's impact); beyond
(1 + BLEND) times it, the compliant landing."""


def edge_asymmetry(scene: Scene, hit: BoxImpact):
    """How unequally the two vertices of the struck edge along the depth (e3) meet the ground, relative to the
    approach speed: (|difference of their approach speeds| + |slip along the edge|) / |approach speed|, before
    the impact. 0 for motion in the plane."""
    d, e3 = scene.drop, hit.attitude[:, 2]
    w = d.angular_velocity()
    u = d.velocity() + jnp.cross(w, hit.r)
    spread = jnp.cross(w, scene.housing.depth * e3)[1]
    return (jnp.abs(spread) + jnp.abs(u @ e3)) / jnp.maximum(jnp.abs(u[1]), jnp.finfo(u.dtype).tiny)


def edge_weight(scene: Scene, hit: BoxImpact):
    """Under `"auto"`, the share of a box's first impact that its edge along the depth takes as one contact (the
    plane section's impact, exact at tilt = 0 with the motion in the plane) rather than its lowest vertex alone
    (the 3D rigid law) or, where the edge's vertices strike unequally, the compliant landing: 1 for the plane
    section's drop (`plane_drop`), the smoothstep in the edge's other vertex's strike time (`box_strike_times`)
    over one to three contact durations, as `compliant_weight`'s, for a tilted drop; times the smoothstep in
    `edge_asymmetry` over `ASYMMETRY` to (1 + `BLEND`) `ASYMMETRY` where the motion leaves the plane; 0 for tilts
    beyond 90 deg, where the edge is not the plane's."""
    tau = scene.contact.duration
    t_edge = box_strike_times(scene, hit)[0]
    d = scene.drop
    near = jnp.where(d.tilt == 0, 1.0, jnp.where(jnp.cos(d.tilt) > 0, _smoothstep(t_edge, tau), 0.0))
    return near * jnp.where(d.in_plane(), 1.0, _smoothstep(edge_asymmetry(scene, hit), ASYMMETRY))


def first_jumps(scene: Scene, numerics: Numerics, plane_jumps):
    """The first impact's rigid-motion inputs (dvA, dvB, dvR) and the box's impact (None for a plane section):
    `drop_jumps`, and under `"auto"` a box's blended with its edge's as one contact (`edge_weight`)."""
    jumps, box = drop_jumps(scene, plane_jumps, numerics.law, numerics.from_rest)
    if box is not None and scene.contact.model == "auto" and numerics.max_impacts == 1:
        # At tilt 0 the rigid law's part is the edge's, whatever the motion: where the edge strikes unequally the
        # compliant landing takes the rest (`box_compliant_weight`).
        w_edge = jnp.where(scene.drop.tilt == 0, 1.0, edge_weight(scene, box))
        plane = jnp.concatenate([plane_jumps, jnp.zeros_like(jumps[:1])])
        jumps = w_edge * plane + (1.0 - w_edge) * jumps
    return jumps, box


def box_compliant_weight(scene: Scene, numerics: Numerics, plane_weight):
    """A box's compliant share under `"auto"`: where its edge along the depth lands as one contact
    (`edge_weight`), the plane section's (`plane_weight`); where the lowest vertex strikes alone, 1 if other
    vertices are level with it (an edge or a face out of the plane), else the smoothstep in the next of the other
    six vertices' strike times, as the plane's."""
    hit = box_housing_impact(scene, numerics.law, numerics.from_rest)
    w_edge = edge_weight(scene, hit)
    tau = scene.contact.duration
    t_edge, t_others = box_strike_times(scene, hit)
    # With motion out of the plane the edge's other vertex is one more strike that may overlap the first.
    t_next = jnp.where(scene.drop.in_plane(), t_others, jnp.minimum(t_edge, t_others))
    others = jnp.where(hit.tied & ~plane_drop(scene), 1.0, _smoothstep(t_next, tau))
    return w_edge * plane_weight + (1.0 - w_edge) * others


FIRST_LANDING_STEPS = 8192
"""The step limit of a first solve of a concrete near-flat drop (`simulate`, `solve_landings`, Monte-Carlo's
orientation table), solved again with `Numerics.landing_steps` where it is not enough: near-flat drops of the
default beam took 1000 to 2300 steps, of the JESD22 plate 5500 to 10,900 (2 of its 416 table nodes more than
8192), nearly plastic ones (restitution 0.012-0.017) of the beam up to 6100. The solve's buffer of states is
allocated at the limit: with this one (against 16384) an orientation table's node of the default beam took 7.7-8.3
against 9.8-10.1 ms, to the same numbers; a single drop's time moved less than its noise (the default scene at
0.5 deg 22-37 ms, the JESD22 plate 158-188 ms, with either)."""


def _velocity(scene: Scene):
    d = scene.drop
    return jnp.stack([d.horizontal_speed, -jnp.sqrt(2.0 * GRAVITY * jnp.maximum(d.height, 0.0))])


def scene_landing(scene: Scene, window, max_steps: int = 16384, tolerance: float = 1e-10,
                  kinks: bool = True) -> Landing | BoxLanding:
    """The compliant landing of a drop, integrated from the first touch to `window` (s) through every strike: the
    plane section's (`Landing`) or a box's (`BoxLanding`). `max_steps`: the solve's step limit (the buffer of
    the states it keeps at each step; `FIRST_LANDING_STEPS`); beyond it the drop is flagged
    `SOLVER_FAILED`. `tolerance`: the step controller's rtol and atol on the nondimensional state; `kinks=False`:
    it steps across the contacts' kinks (`Numerics.landing_kinks`)."""
    h, c, d = scene.housing, scene.contact, scene.drop
    nan = jnp.asarray(jnp.nan, dtype=jnp.result_type(float))
    if h.is_box:
        return box_landing(h.width, h.height, h.depth, h.mass, h.moments, c.friction, c.restitution, c.duration,
                           d.orientation, d.tilt, d.velocity(), d.angular_velocity(),
                           jnp.asarray(GRAVITY, dtype=nan.dtype), nan, window, rtol=tolerance, atol=tolerance,
                           max_steps=max_steps, through=True, kinks=kinks)
    return _landing(h.width, h.height, h.mass, h.inertia, c.friction, c.restitution, c.duration, d.orientation,
                    _velocity(scene), d.spin, jnp.asarray(GRAVITY, dtype=nan.dtype), nan, window, rtol=tolerance,
                    atol=tolerance, max_steps=max_steps, through=True, kinks=kinks)


def landing_motion(scene: Scene, numerics: Numerics, weight, rigid_jumps, samples: int = LANDING_SAMPLES,
                   modal=None) -> tuple[LandingMotion, Landing]:
    """The supports' normal acceleration through the compliant landing (`weight` of it, blended with the rigid
    law's half-sine of jumps `rigid_jumps`), sampled on the peak window, and the `Landing`. `modal`: the board's
    solved modes, where the caller has them (`landing_window`)."""
    window = landing_window(scene, numerics, modal)
    landing = scene_landing(scene, window, numerics.landing_steps, numerics.landing_tolerance, numerics.landing_kinks)
    t = jnp.linspace(0.0, 1.0, samples) * window
    if scene.housing.is_box:
        return _box_landing_motion(scene, numerics, weight, rigid_jumps, landing, t, window)
    ends = board_ends(scene.placement, scene.board.length)
    # Each sample is the mean contact acceleration over the interval of one sample spacing around it, from the
    # contact velocity at the interval's ends: a corner's touch (a jump in its force) then moves the samples
    # smoothly as the drop changes, and their gradient is that of the sampled drive (point samples of the force
    # would jump as the touch crosses a sample, which a gradient does not see).
    dt = window / (samples - 1)
    edges = landing.contact_velocity(jnp.linspace(-0.5, samples - 0.5, samples + 1) * dt, ends)  # (samples + 1, 2, 2)
    acc = (edges[1:] - edges[:-1]) / dt  # (samples, 2 ends, 2)
    # Along the board normal n = z x t (as `support_jumps`), t the board's axis in the ground frame.
    axis = _in_ground(jnp.stack(sincos(scene.placement.angle)[::-1]), *sincos(scene.drop.orientation))
    compliant = acc[..., 1] * axis[0] - acc[..., 0] * axis[1]
    compliant = jnp.concatenate([compliant, jnp.zeros_like(compliant[:, :1])], axis=-1)  # the plane: no roll
    return _blend(scene, weight, rigid_jumps, t, compliant), landing


def _blend(scene, weight, rigid_jumps, t, compliant):
    rigid = jax.vmap(HalfSine(rigid_jumps[0], rigid_jumps[1], scene.contact.duration, rigid_jumps[2]).acceleration)(t)
    a = weight * compliant + (1.0 - weight) * rigid
    return LandingMotion(t, a[:, 0], a[:, 1], scene.contact.duration, weight, a[:, 2])


def _box_landing_motion(scene: Scene, numerics: Numerics, weight, rigid_jumps, landing: BoxLanding, t, window):
    """`landing_motion` on a box: the three rigid-motion inputs (heave at ends A and B, roll across the width) along
    the board normal, from the contact velocity at the ends and at the board's centre +- half its width along e3
    (as `box_support_jumps` reads the rigid law's jumps)."""
    p = scene.placement
    ends = board_ends(p, scene.board.length)
    centre = 0.5 * (ends[0] + ends[1])
    z = jnp.broadcast_to(p.depth_offset, ends.shape[:-1])
    half = 0.5 * scene.board.width
    points = jnp.stack([jnp.concatenate([ends[0], z[:1]]), jnp.concatenate([ends[1], z[1:]]),
                        jnp.concatenate([centre, (p.depth_offset + half)[None]]),
                        jnp.concatenate([centre, (p.depth_offset - half)[None]])])
    samples = t.shape[0]
    dt = window / (samples - 1)
    edges = landing.contact_velocity(jnp.linspace(-0.5, samples - 0.5, samples + 1) * dt, points)  # (n+1, 4, 3)
    s, c = sincos(p.angle)
    normal = landing.attitude @ jnp.stack([-s, c, jnp.zeros_like(s)])
    along = edges @ normal  # (n + 1, 4)
    acc = (along[1:] - along[:-1]) / dt
    compliant = jnp.stack([acc[:, 0], acc[:, 1], acc[:, 2] - acc[:, 3]], axis=-1)
    return _blend(scene, weight, rigid_jumps, t, compliant), landing


class LandingHistories(eqx.Module):
    """A drop's landing over the peak window, for figures and tables: times `t` (s), each corner's normal force
    `forces` (n, 4) (N, corners in `housing_corners`' order; a box's vertices (n, 8) in `box_vertices`' order), the supports' normal acceleration `support` (n, 2)
    (m/s^2, ends A and B; blended as `simulate` uses it) and the rigid law's half-sine `rigid` (n, 2), and the
    compliant landing's `weight`."""

    t: Float[Array, " n"]
    forces: Float[Array, "n k"]
    support: Float[Array, "n 2"]
    rigid: Float[Array, "n 2"]
    weight: Float[Array, ""]


@filter_jit
def landing_histories(scene: Scene, numerics: Numerics) -> LandingHistories:
    """The landing of a concrete drop as `LandingHistories` (the compliant landing whatever `Contact.model`; its
    `weight` is the model's)."""
    hit = housing_impact(scene, law=numerics.law)
    jumps = first_jumps(scene, numerics, _support_jumps(scene, hit, scene.drop.orientation))[0]
    weight = compliant_weight(scene, numerics, hit)
    motion, landing = landing_motion(scene, numerics, jnp.ones_like(weight), jumps)
    rigid = jax.vmap(HalfSine(jumps[0], jumps[1], scene.contact.duration, jumps[2]).acceleration)(motion.t)[:, :2]
    return LandingHistories(motion.t, landing.forces(motion.t)[..., 1], jnp.stack([motion.aA, motion.aB], -1),
                            rigid, weight)
