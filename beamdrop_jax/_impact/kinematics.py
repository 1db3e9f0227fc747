"""Housing kinematics: which corner strikes, the contact's inverse inertia, and the velocity jumps an impact gives.

Ground frame: x horizontal, y up, counter-clockwise positive. Body axes e1 = (cos theta, sin theta) along the width,
e2 = (-sin theta, cos theta). r = G - S is the centre of mass seen from the striking corner S.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._common.checks import GRAVITY, Flag, array_module, combine, flag_if, is_concrete
from .._common.compile import filter_jit
from .box import BoxImpact, box_impact
from .routh import ImpactMode, ImpactResult, routh_impulse
from .._scene.containers import Scene, board_ends
from .._common.trig import sincos


def body_axes(orientation) -> Float[Array, "2 2"]:
    """Rows e1, e2 of the housing's body axes in the ground frame (NumPy's for a NumPy or Python number)."""
    xp = array_module(orientation)  # NumPy in plots: no program to compile
    s, c = sincos(orientation) if xp is jnp else (np.sin(orientation), np.cos(orientation))
    return xp.stack([xp.stack([c, s]), xp.stack([-s, c])])


def _in_ground(q, s, c):
    """Body coordinates q (..., 2) in the ground frame, for an orientation with sine s and cosine c. Written out
    rather than as `q @ body_axes`: under vmap a batch of 2 x 2 products is a separate, slow XLA op, while these
    products fuse with the rest of a drop's arithmetic."""
    q1, q2 = q[..., 0], q[..., 1]
    return jnp.stack([q1 * c - q2 * s, q1 * s + q2 * c], axis=-1)


def _flat_tolerance(x):
    return 64 * jnp.finfo(jnp.asarray(x).dtype).eps


def lowest_corner(scene: Scene) -> tuple[Float[Array, "2"], Float[Array, "2"], Array]:
    """The striking corner.

    **Returns:** `(corner, r, flat)`: the corner's body coordinates (q1, q2) from G (m), r = G - S in the ground
    frame (m, r[1] > 0), and whether two corners are equally low (a flat landing on a face).
    """
    return lowest_corner_at(scene.drop.orientation, scene.housing.width, scene.housing.height)


def lowest_corner_at(orientation, width, height):
    """`lowest_corner` for a housing of `width` x `height` at any `orientation` (rad)."""
    th = orientation
    s, c = sincos(th)
    # The corner +-W/2 e1 +-H/2 e2 lies lowest when each sign opposes the y-component of its axis.
    a = jnp.where(s > 0, -1.0, 1.0)
    b = jnp.where(c > 0, -1.0, 1.0)
    corner = jnp.stack([a * width / 2, b * height / 2])
    r = -_in_ground(corner, s, c)
    tol = _flat_tolerance(th)
    flat = (jnp.abs(s) < tol) | (jnp.abs(c) < tol)
    return corner, r, flat


def contact_matrix(r: Float[Array, "2"], mass, inertia) -> Float[Array, "2 2"]:
    """Inverse inertia at the contact, B = [[B1, -B3], [-B3, B2]] with B1 = 1/m + y^2/I, B2 = 1/m + x^2/I,
    B3 = x y / I, for r = G - S = (x, y)."""
    x, y = r[0], r[1]
    B1 = 1.0 / mass + y**2 / inertia
    B2 = 1.0 / mass + x**2 / inertia
    B3 = x * y / inertia
    return jnp.stack([jnp.stack([B1, -B3]), jnp.stack([-B3, B2])])


def approach_velocity(scene: Scene, r: Float[Array, "2"]) -> Float[Array, "2"]:
    """Contact-point velocity (S0, C0) before impact: S0 = u + w0 y, C0 = -sqrt(2 g h) - w0 x (m/s)."""
    d = scene.drop
    v_drop = jnp.sqrt(2.0 * GRAVITY * jnp.maximum(d.height, 0.0))
    return jnp.stack([d.horizontal_speed + d.spin * r[1], -v_drop - d.spin * r[0]])


class HousingImpact(eqx.Module):
    """The housing's impact: the law's result plus what it does to the rigid body.

    - `impact`: the `ImpactResult` (impulse P in the ground frame's (t, n) = (x, y) directions).
    - `corner`: striking corner's body coordinates from G, m. `r`: G - S in the ground frame, m.
    - `B`, `v0`: contact inverse inertia and approach velocity (S0, C0).
    - `dv_G`: jump of the centre-of-mass velocity, m/s. `dw`: jump of the spin, rad/s.
    - `flat`: whether the housing landed flat on a face (then the exact translation answer is used).
    - `flags`: `Flag` mask.
    """

    impact: ImpactResult
    corner: Float[Array, "2"]
    r: Float[Array, "2"]
    B: Float[Array, "2 2"]
    v0: Float[Array, "2"]
    dv_G: Float[Array, "2"]
    dw: Float[Array, ""]
    flat: Array
    flags: Int[Array, ""]

    def point_velocity_jump(self, orientation, q: Float[Array, "... 2"]) -> Float[Array, "... 2"]:
        """Velocity jump (ground frame, m/s) of housing points at body coordinates q = (q1, q2) from G."""
        r_q = _in_ground(jnp.asarray(q), *sincos(orientation))
        z_cross = jnp.stack([-r_q[..., 1], r_q[..., 0]], axis=-1)
        return self.dv_G + self.dw * z_cross


def housing_impact(scene: Scene, law: str = "poisson") -> HousingImpact:
    """Corner impact of the dropped housing: lowest corner, Routh impulse, jumps of v_G and spin.

    A flat landing (two corners equally low) with no spin and no horizontal speed has the exact answer that the
    housing translates: every point gains (1 + e) times the approach speed upwards and friction plays no part
    (`impact.P` then holds the total impulse of both corners). A flat landing with spin or drift is outside the
    single-contact law: `Flag.FLAT_LANDING_WITH_MOTION`. A separating contact (C0 >= 0, e.g. a zero drop height)
    gets `Flag.SEPARATING_CONTACT`.
    """
    if is_concrete(scene):  # one compiled program, not one per operation; a flagged impact is redone eagerly
        hit = _housing_impact_program(scene, law)
        if not int(hit.flags):
            return hit
    hit = _housing_impact(scene, law)
    d = scene.drop
    moving = (d.spin != 0) | (d.horizontal_speed != 0)
    _raise_outside_law(scene, hit.flat & moving, ~(hit.v0[1] < 0), hit.v0)
    return hit


def _housing_impact(scene: Scene, law: str) -> HousingImpact:
    d = scene.drop
    velocity = jnp.stack([d.horizontal_speed, -jnp.sqrt(2.0 * GRAVITY * jnp.maximum(d.height, 0.0))])
    return corner_impact(scene.housing, scene.contact, d.orientation, velocity, d.spin, law=law)


_housing_impact_program = filter_jit(_housing_impact)


def corner_impact(housing, contact, orientation, velocity, spin, law: str = "poisson") -> HousingImpact:
    """Impact of the lowest corner of `housing` at `orientation` (rad), its centre of mass moving at `velocity`
    (vx, vy) (m/s) and spinning at `spin` (rad/s) just before; `housing_impact` for any state (a clattering
    drop's later impacts). Flags as in `housing_impact`."""
    h = housing
    corner, r, flat = lowest_corner_at(orientation, h.width, h.height)
    B = contact_matrix(r, h.mass, h.inertia)
    v0 = velocity + spin * jnp.stack([r[1], -r[0]])
    imp = routh_impulse(B, v0, contact.friction, contact.restitution, law=law)
    dv_G = imp.P / h.mass
    dw = (r[1] * imp.P[0] - r[0] * imp.P[1]) / h.inertia

    e = contact.restitution
    flat_P = jnp.stack([jnp.zeros_like(v0[1]), -(1.0 + e) * h.mass * v0[1]])
    flat_impact = ImpactResult(
        P=flat_P,
        Pn_compression=-h.mass * v0[1],
        Pn_stick=jnp.zeros_like(v0[1]),
        mode=jnp.int32(ImpactMode.STICK_IN_COMPRESSION),
        velocity=jnp.stack([jnp.zeros_like(v0[1]), -e * v0[1]]),
        energy_change=0.5 * h.mass * (e**2 - 1.0) * v0[1] ** 2,
        path=jnp.stack([jnp.zeros(2, dtype=flat_P.dtype), flat_P / 2, flat_P]),
        flags=imp.flags,
    )
    moving = (spin != 0) | (velocity[0] != 0)
    impact = jnp_tree_where(flat, flat_impact, imp)
    dv_G = jnp.where(flat, flat_P / h.mass, dv_G)
    dw = jnp.where(flat, 0.0, dw)
    flags = combine(
        impact.flags,
        flag_if(flat & moving, Flag.FLAT_LANDING_WITH_MOTION),
        flag_if(~(v0[1] < 0), Flag.SEPARATING_CONTACT),
    )
    return HousingImpact(impact, corner, r, B, v0, dv_G, dw, flat, flags)


def _raise_outside_law(scene, flat_moving, separating, v0):
    if not is_concrete(flat_moving, separating, v0):
        return
    d = scene.drop
    if bool(flat_moving):
        raise ValueError(
            f"Drop.orientation = {float(d.orientation):.6g} rad lands flat on a face (a multiple of pi/2) with "
            f"Drop.spin = {float(d.spin):g} rad/s and Drop.horizontal_speed = {float(d.horizontal_speed):g} m/s: two "
            "simultaneous contacts are outside the single-contact law. Use spin = 0 and horizontal_speed = 0 for a "
            "flat landing (exact translation answer), or an orientation away from multiples of pi/2."
        )
    if bool(separating):
        raise ValueError(
            f"the striking corner's normal velocity C0 = {float(v0[1]) + 0.0:g} m/s does not approach the ground "
            f"(C0 must be < 0): Drop.height = {float(d.height):g} m, Drop.spin = {float(d.spin):g} rad/s. Use "
            "Drop.height > 0 (up to 1000 m), or at Drop.height = 0 a spin that moves the lowest corner down."
        )


def jnp_tree_where(cond, a, b):
    """Elementwise `jnp.where(cond, a, b)` over two pytrees of the same structure."""
    return jax.tree_util.tree_map(lambda x, y: jnp.where(cond, x, y), a, b)


def support_jumps(scene: Scene, hit: HousingImpact, orientation=None) -> Float[Array, "2"]:
    """Normal velocity jumps (dvA, dvB) of the board's ends, m/s, positive along the board normal n = z x t, for
    the housing at `orientation` (default: the drop's) when `hit` strikes."""
    orientation = scene.drop.orientation if orientation is None else orientation
    if is_concrete(scene, hit, orientation):  # one compiled program, not one per operation
        return _support_jumps_program(scene, hit, jnp.asarray(orientation))  # an array: not a static argument
    return _support_jumps(scene, hit, orientation)


def _support_jumps(scene: Scene, hit: HousingImpact, orientation) -> Float[Array, "2"]:
    ends = board_ends(scene.placement, scene.board.length)
    dv = hit.point_velocity_jump(orientation, ends)
    phi = scene.placement.angle
    t = _in_ground(jnp.stack(sincos(phi)[::-1]), *sincos(orientation))
    return dv[..., 1] * t[0] - dv[..., 0] * t[1]  # along n = z x t = (-t_y, t_x)


_support_jumps_program = filter_jit(_support_jumps)


def box_housing_impact(scene: Scene, law: str = "poisson", from_rest: bool = False) -> BoxImpact:
    """The first impact of a box housing (`Housing.depth`): its lowest vertex (an edge's midpoint or a face's centre
    where several are equally low) struck under the 3D rigid law (`bd.box_impact`), G falling from `Drop.height`
    at `Drop.velocity()` and turning at `Drop.angular_velocity()` (`from_rest`, static: no spin and no horizontal
    speed, the law's closed form)."""
    h, d, c = scene.housing, scene.drop, scene.contact
    if not h.is_box:
        raise ValueError("box_housing_impact needs a box housing: give Housing.depth (m)")
    return box_impact(h.mass, h.width, h.height, h.depth, h.moments, d.orientation, d.tilt, d.velocity(),
                      d.angular_velocity(), c.friction, c.restitution, law=law, from_rest=from_rest)


def box_support_jumps(scene: Scene, hit: BoxImpact) -> Float[Array, "3"]:
    """The board's rigid-motion inputs (dvA, dvB, dvR) (m/s, `bd.HalfSine`) from a box housing's impact: the
    velocity jump dV + dOmega x r of each end A, B (on the board's centre line, at `Placement.depth_offset` along
    e3) and across the board's width along e3, projected on the board normal (e3 x t in the body frame)."""
    p = scene.placement
    ends = board_ends(p, scene.board.length)  # (2, 2) body (q1, q2)
    z = jnp.broadcast_to(p.depth_offset, ends.shape[:-1])[..., None]
    s, c = sincos(p.angle)
    normal = hit.attitude @ jnp.stack([-s, c, jnp.zeros_like(s)])  # ground frame
    ends_dv = hit.body_point_velocity_jump(jnp.concatenate([ends, z], axis=-1)) @ normal
    across = jnp.cross(hit.dOmega, hit.attitude[:, 2]) @ normal * scene.board.width
    return jnp.concatenate([ends_dv, across[None]])


def drop_jumps(scene: Scene, plane_jumps: Float[Array, "2"], law: str = "poisson", from_rest: bool = False):
    """The first impact's rigid-motion inputs (dvA, dvB, dvR) of the board and the box's impact (None for a
    plane section): a plane section's, or a box's at tilt = 0 with its motion in the plane (`plane_drop`), are
    `plane_jumps` with no roll (a box on an edge along e3, struck with motion in the plane, is the plane section
    exactly); any other box's come from its 3D impact (`box_support_jumps`)."""
    plane = jnp.concatenate([plane_jumps, jnp.zeros_like(plane_jumps[:1])])
    if not scene.housing.is_box:
        return plane, None
    hit = box_housing_impact(scene, law, from_rest)
    return jnp.where(plane_drop(scene), plane, box_support_jumps(scene, hit)), hit


def plane_drop(scene: Scene):
    """Whether a drop is the plane section's: no tilt and motion in the plane of motion (a box then lands on an
    edge along e3, struck symmetrically about its mid-depth)."""
    return (scene.drop.tilt == 0) & scene.drop.in_plane()
