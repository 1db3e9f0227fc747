"""Landings where corners strike together: which contact model a drop takes (`Contact.model`) and the supports'
motion through a compliant landing (DESIGN.md section 7).

**What `"auto"` follows.** The board's peak window runs from the first touch to one contact duration plus the
board's fundamental period (the rigid law's window). `"auto"` follows every strike that begins in it: where the
first corner strikes alone in the window, that is the rigid law's single strike (today's numbers, closed form);
where another corner strikes in it (near-flat landings, and drops whose far corner slaps down soon after), the
compliant landing integrates the housing's rigid motion through the whole window, every strike in it included,
and the board feels the supports' acceleration history. The switch is decided by the rigid law's own prediction
of the next strike, `t2`: compliant for `t2 <= window - blend`, rigid for `t2 >= window`, and in between the
supports' acceleration is the blend `w a_compliant + (1 - w) a_rigid` with `w` a smoothstep in `t2`, so the answer
has no jump where a strike leaves the window (a strike at the window's end adds almost nothing to the peak in it,
and the blend absorbs the small difference between the two contact laws on the first strike). A flat landing (two
corners equally low) is always compliant. `"rigid"` follows the first strike only (as the thesis did);
`Numerics(max_impacts=K)` follows K rigid strikes whatever the model.
"""

import jax
import jax.numpy as jnp

from .._common.checks import GRAVITY
from .._impact.clatter import next_contact
from .._impact.kinematics import HousingImpact, _in_ground
from .._impact.landing import Landing, _landing
from .._impact.motion import HalfSine, LandingMotion
from .._scene.containers import Scene, board_ends
from .._common.trig import sincos
from .numerics import Numerics
from .pulses import fundamental_period

LANDING_SAMPLES = 1024
"""Samples of the supports' acceleration over the peak window (a 0.5 ms contact in a 7 ms window gets 70)."""

BLEND = 0.25
"""Width of the blend at the window's end, as a fraction of the window."""


def landing_window(scene: Scene, numerics: Numerics):
    """The board's peak window after the first touch, s: `Numerics.window`, or one contact duration plus the
    board's fundamental period."""
    if numerics.window is not None:
        return jnp.asarray(numerics.window, dtype=jnp.result_type(float))
    return scene.contact.duration + fundamental_period(scene.board)


def next_strike_time(scene: Scene, hit: HousingImpact):
    """When the next corner strikes after the rigid law's first strike `hit` (free flight from it), s; inf when
    the search finds none."""
    d, h = scene.drop, scene.housing
    v = jnp.stack([d.horizontal_speed, -jnp.sqrt(2.0 * GRAVITY * jnp.maximum(d.height, 0.0))]) + hit.dv_G
    s, _, found = next_contact(h.width, h.height, hit.r[1], v[1], d.orientation, d.spin + hit.dw)
    return jnp.where(found, s, jnp.inf)


def compliant_weight(scene: Scene, numerics: Numerics, hit: HousingImpact):
    """The compliant landing's share of the supports' motion (0: the rigid law alone, 1: the landing alone), by
    `Contact.model` (module notes)."""
    model = scene.contact.model
    if model == "rigid":
        return jnp.zeros_like(scene.contact.duration)
    if model == "compliant":
        return jnp.ones_like(scene.contact.duration)
    window = landing_window(scene, numerics)
    t2 = jax.lax.stop_gradient(next_strike_time(scene, hit))  # the switch's position; its kink is not a gradient
    u = jnp.clip((window - t2) / (BLEND * window), 0.0, 1.0)
    w = jnp.where(hit.flat, 1.0, u * u * (3.0 - 2.0 * u))
    return jnp.where(scene.contact.duration > 0, w, 0.0)


def _velocity(scene: Scene):
    d = scene.drop
    return jnp.stack([d.horizontal_speed, -jnp.sqrt(2.0 * GRAVITY * jnp.maximum(d.height, 0.0))])


def scene_landing(scene: Scene, window, max_steps: int = 32768) -> Landing:
    """The compliant landing of a drop, integrated from the first touch to `window` (s) through every strike."""
    h, c, d = scene.housing, scene.contact, scene.drop
    nan = jnp.asarray(jnp.nan, dtype=jnp.result_type(float))
    return _landing(h.width, h.height, h.mass, h.inertia, c.friction, c.restitution, c.duration, d.orientation,
                    _velocity(scene), d.spin, jnp.asarray(GRAVITY, dtype=nan.dtype), nan, window, rtol=1e-10,
                    atol=1e-10, max_steps=max_steps, through=True)


def landing_motion(scene: Scene, numerics: Numerics, weight, rigid_jumps,
                   samples: int = LANDING_SAMPLES) -> tuple[LandingMotion, Landing]:
    """The supports' normal acceleration through the compliant landing (`weight` of it, blended with the rigid
    law's half-sine of jumps `rigid_jumps`), sampled on the peak window, and the `Landing`."""
    window = landing_window(scene, numerics)
    landing = scene_landing(scene, window)
    t = jnp.linspace(0.0, 1.0, samples) * window
    ends = board_ends(scene.placement, scene.board.length)
    acc = landing.contact_acceleration(t, ends)  # (samples, 2 ends, 2)
    # Along the board normal n = z x t (as `support_jumps`), t the board's axis in the ground frame.
    axis = _in_ground(jnp.stack(sincos(scene.placement.angle)[::-1]), *sincos(scene.drop.orientation))
    compliant = acc[..., 1] * axis[0] - acc[..., 0] * axis[1]
    rigid = jax.vmap(HalfSine(rigid_jumps[0], rigid_jumps[1], scene.contact.duration).acceleration)(t)
    a = weight * compliant + (1.0 - weight) * rigid
    return LandingMotion(t, a[:, 0], a[:, 1], scene.contact.duration, weight), landing
