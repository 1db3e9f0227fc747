"""A box housing's rigid kinematics for a single-vertex strike (DESIGN.md section 7): attitude, the lowest vertex,
the contact's inverse inertia and the velocity jumps that `impulse_3d`'s impulse gives the body.

**Frames.** Ground: x horizontal in the plane of motion, y up, z out of the plane. The box has half-extents
(W/2, H/2, D/2) along its body axes e1, e2, e3 (width, height, depth), G at its centre. Its attitude
R = Rx(tilt) Rz(orientation) holds e1, e2, e3 as columns in the ground frame: Rz(orientation) gives the plane
section's axes exactly (`body_axes`: e1 = (cos theta, sin theta, 0), e2 = (-sin theta, cos theta, 0)), and the tilt
then turns the box about the ground's x axis (right-handed: +y goes towards +z), so tilt = 0 is the plane drop.

**Contact frame.** `impulse_3d` works in (t1, t2, n) = (x, z, y): a permutation of the ground axes (left-handed, which
does not matter: K and the impulse transform as a matrix and a vector under any orthogonal map, and every cross
product here is taken in the ground frame).

Unlike the plane code's `HousingImpact.r` (G - S), the arm r here runs from G to the struck vertex S.
"""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .._common.checks import Flag, combine, flag_if, require
from .._common.compile import jit
from .._common.trig import sincos
from .impulse3d import Impact3D, impulse_3d

# Ground (x, y, z) -> contact (t1, t2, n) = (x, z, y); the permutation is its own inverse.
_CONTACT_AXES = (0, 2, 1)


def box_inertia(mass, width, height, depth) -> Float[Array, "3"]:
    """Principal moments of inertia (kg m^2) of a uniform box about G, about e1, e2, e3:
    m (H^2 + D^2) / 12, m (W^2 + D^2) / 12, m (W^2 + H^2) / 12. The last is the plane section's default
    m k^2 with k = sqrt((W^2 + H^2) / 12)."""
    w2, h2, d2 = jnp.square(width), jnp.square(height), jnp.square(depth)
    return mass / 12.0 * jnp.stack([h2 + d2, w2 + d2, w2 + h2])


def box_attitude(orientation, tilt) -> Float[Array, "3 3"]:
    """Rotation R = Rx(tilt) Rz(orientation) (rad): its columns are the body axes e1, e2, e3 in the ground frame."""
    s, c = sincos(jnp.asarray(orientation))
    st, ct = sincos(jnp.asarray(tilt))
    zero = jnp.zeros_like(s * st)
    # Rx(tilt) @ Rz(orientation) written out.
    return jnp.stack([
        jnp.stack([c + zero, -s + zero, zero]),
        jnp.stack([ct * s, ct * c, -st + zero]),
        jnp.stack([st * s, st * c, ct + zero]),
    ])


def box_vertices(width, height, depth) -> Float[Array, "8 3"]:
    """The eight vertices in body coordinates from G (m); vertex i has signs (+ where bit set) of
    (i >> 2 & 1, i >> 1 & 1, i & 1) along (e1, e2, e3)."""
    half = jnp.stack(jnp.broadcast_arrays(*(jnp.asarray(x) for x in (width, height, depth)))) / 2
    bits = jnp.array([[(i >> 2) & 1, (i >> 1) & 1, i & 1] for i in range(8)])
    return jnp.where(bits == 1, 1.0, -1.0).astype(half.dtype) * half


class LowestVertex(eqx.Module):
    """The vertex that strikes (`lowest_vertex`).

    - `index`: its row in `box_vertices`. `vertex`: its body coordinates from G, m; where two or four vertices are
      equally low (`tied`), the midpoint of that edge or the centre of that face (the point where their equal
      impulses act when the motion is symmetric about the level axes).
    - `r`: the arm from G to it in the ground frame, m (r[1] < 0: G's height above it is -r[1]).
    - `clearance`: how far the next-lowest vertex lies above it, m (0 on an edge or a face).
    - `tied`: whether two or more vertices are equally low (an axis within 64 eps of horizontal): an edge or face
      landing, outside the single-vertex law.
    """

    index: Int[Array, ""]
    vertex: Float[Array, "3"]
    r: Float[Array, "3"]
    clearance: Float[Array, ""]
    tied: Bool[Array, ""]


def _lowest(R, width, height, depth) -> LowestVertex:
    half = jnp.stack(jnp.broadcast_arrays(*(jnp.asarray(x) for x in (width, height, depth)))) / 2
    up = R[1]  # the body axes' upward components
    # Each sign opposes its axis' upward component; a level axis takes +, as `lowest_corner_at` does, for the
    # index, and its midpoint for the struck point.
    plus = ~(up > 0)
    tol = 64 * jnp.finfo(R.dtype).eps
    level = jnp.abs(up) < tol
    vertex = jnp.where(level, 0.0, jnp.where(plus, half, -half))
    index = jnp.sum(jnp.where(plus, jnp.array([4, 2, 1]), 0)).astype(jnp.int32)
    return LowestVertex(index=index, vertex=vertex, r=R @ vertex, clearance=2.0 * jnp.min(jnp.abs(up) * half),
                        tied=jnp.any(level))


def lowest_vertex(orientation, tilt, width, height, depth) -> LowestVertex:
    """The lowest vertex of a `width` x `height` x `depth` box (m) at `orientation` and `tilt` (rad). Its arm `r`
    is differentiable in the angles and sizes wherever one vertex is strictly lowest."""
    return _lowest(box_attitude(orientation, tilt), width, height, depth)


def _cross_matrix(r):
    """[r]x: [r]x a = r x a."""
    zero = jnp.zeros_like(r[0])
    return jnp.stack([jnp.stack([zero, -r[2], r[1]]), jnp.stack([r[2], zero, -r[0]]),
                      jnp.stack([-r[1], r[0], zero])])


def _contact_matrix(r, mass, inverse_inertia):
    X = _cross_matrix(r)
    K = jnp.eye(3, dtype=X.dtype) / mass + X.T @ inverse_inertia @ X
    K = 0.5 * (K + K.T)  # symmetric to the last bit: impulse_3d checks it
    return K[jnp.array(_CONTACT_AXES)][:, jnp.array(_CONTACT_AXES)]


def vertex_contact_matrix(r_world: Float[Array, "3"], mass, inertia_world: Float[Array, "3 3"]) -> Float[Array, "3 3"]:
    """Inverse inertia (1/kg) at a point at arm `r_world` (m, from G, ground frame) of a rigid body of `mass` (kg)
    and inertia tensor `inertia_world` (kg m^2, about G, ground frame, e.g. R diag(I) R^T):
    K = (1/m) 1 + [r]x^T I^-1 [r]x, in the contact frame (t1, t2, n) = (x, z, y) that `impulse_3d` takes."""
    return _contact_matrix(r_world, mass, jnp.linalg.inv(inertia_world))


class BoxImpact(eqx.Module):
    """A box's single-vertex impact: the law's result and what it does to the rigid body.

    - `impact`: the `Impact3D` (impulse and velocities in the contact frame (t1, t2, n) = (x, z, y)).
    - `r`: arm from G to the struck point, ground frame, m. `attitude`: R (body axes as columns).
    - `K`, `u0`: the contact's inverse inertia (1/kg) and approach velocity (m/s), contact frame.
    - `P`: the impulse in the ground frame (x, y, z), N s.
    - `dV`: jump of G's velocity (m/s); `dOmega`: jump of the angular velocity (rad/s), ground frame.
    - `tied`: several vertices equally low (`LowestVertex.tied`): an edge or a face strikes, and the law acts at
      its midpoint (exact when the motion is symmetric about the level axes; else `Flag.FLAT_LANDING_WITH_MOTION`).
    - `flags`: the impact's `Flag` mask.
    """

    impact: Impact3D
    r: Float[Array, "3"]
    attitude: Float[Array, "3 3"]
    K: Float[Array, "3 3"]
    u0: Float[Array, "3"]
    P: Float[Array, "3"]
    dV: Float[Array, "3"]
    dOmega: Float[Array, "3"]
    tied: Bool[Array, ""]
    flags: Int[Array, ""]

    def point_velocity_jump(self, p: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
        """Velocity jump dV + dOmega x p (m/s, ground frame) of body points at arms `p` (m, ground frame, from G)."""
        return self.dV + jnp.cross(self.dOmega, jnp.asarray(p))

    def body_point_velocity_jump(self, q: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
        """`point_velocity_jump` of body points at body coordinates `q` (m, along e1, e2, e3 from G)."""
        return self.point_velocity_jump(jnp.asarray(q) @ self.attitude.T)


@jit
def _approach(r, mass, inverse_inertia, velocity, spin):
    K = _contact_matrix(r, mass, inverse_inertia)
    u0 = (velocity + jnp.cross(spin, r))[jnp.array(_CONTACT_AXES)]
    return K, u0


@jit
def _jumps(r, mass, inverse_inertia, P_contact):
    P = P_contact[jnp.array(_CONTACT_AXES)]
    return P, P / mass, inverse_inertia @ jnp.cross(r, P)


def rigid_vertex_impact(r, mass, inertia_world, velocity, spin, friction, restitution, law: str = "poisson",
                        attitude=None) -> BoxImpact:
    """Impact of the body point at arm `r` (m, from G, ground frame) of a rigid body of `mass` (kg) and inertia
    tensor `inertia_world` (kg m^2 about G, ground frame), G moving at `velocity` (vx, vy, vz) (m/s) and spinning
    at `spin` (wx, wy, wz) (rad/s, ground frame) just before; `friction`, `restitution` and `law` as in
    `impulse_3d`. `attitude` (optional R) is kept for `body_point_velocity_jump` (identity by default); `tied` is
    False: the caller chose the point."""
    r = jnp.asarray(r)
    inverse_inertia = jnp.linalg.inv(jnp.asarray(inertia_world))
    return _vertex_impact(r, mass, inverse_inertia, velocity, spin, friction, restitution, law,
                          jnp.eye(3, dtype=r.dtype) if attitude is None else jnp.asarray(attitude),
                          jnp.asarray(False))


def _vertex_impact(r, mass, inverse_inertia, velocity, spin, friction, restitution, law, attitude, tied,
                   from_rest: bool = False):
    velocity, spin = jnp.asarray(velocity), jnp.asarray(spin)
    if velocity.shape != (3,) or spin.shape != (3,):
        raise ValueError(f"velocity and spin must be 3-vectors (x, y, z) in the ground frame (m/s, rad/s); got "
                         f"shapes {velocity.shape} and {spin.shape} (for many drops, jax.vmap)")
    K, u0 = _approach(r, mass, inverse_inertia, velocity, spin)
    impact = impulse_3d(K, u0, friction, restitution, law=law, from_rest=from_rest)
    P, dV, dOmega = _jumps(r, mass, inverse_inertia, impact.P)
    return BoxImpact(impact=impact, r=r, attitude=attitude, K=K, u0=u0, P=P, dV=dV, dOmega=dOmega, tied=tied,
                     flags=impact.flags)


@jit
def _box_state(orientation, tilt, width, height, depth, inertia):
    R = box_attitude(orientation, tilt)
    return R, _lowest(R, width, height, depth), (R / inertia) @ R.T  # R diag(1/I) R^T


def box_impact(mass, width, height, depth, inertia, orientation, tilt, velocity, spin, friction, restitution,
               law: str = "poisson", *, from_rest: bool = False) -> BoxImpact:
    """Impact of the lowest vertex of a box housing (DESIGN.md section 7, single-vertex strikes).

    **Arguments:** `mass` (kg); `width`, `height`, `depth` (m, along e1, e2, e3); `inertia`: principal moments
    (I1, I2, I3) about e1, e2, e3 through G (kg m^2), or None for a uniform box (`box_inertia`); `orientation` and
    `tilt` (rad, `box_attitude`); `velocity` (vx, vy, vz) of G (m/s, vy < 0 falling) and `spin` (wx, wy, wz)
    (rad/s, ground frame) just before; `friction`, `restitution`, `law` and `from_rest` (no spin, no horizontal
    velocity: the law's closed form) as in `impulse_3d`.

    **Returns:** a `BoxImpact`. At tilt = 0 (or any attitude with a level body axis) the box lands on an edge or a
    face: `tied` is set, and the law acts at the edge's midpoint or the face's centre. By symmetry that is exact
    when G's velocity has no component along the level axes and the spin lies along them (a level axis e3 at
    tilt = 0 with motion in the plane: the plane section's answer); otherwise the strikes are not symmetric and
    the result carries `Flag.FLAT_LANDING_WITH_MOTION`.
    """
    for name, value in (("mass", mass), ("width", width), ("height", height), ("depth", depth)):
        require(value, f"box_impact {name}", lo=0.0, lo_open=True)
    if inertia is None:
        inertia = box_inertia(mass, width, height, depth)
    inertia = jnp.asarray(inertia)
    if inertia.shape != (3,):
        raise ValueError(f"inertia must be the principal moments (I1, I2, I3) about e1, e2, e3, kg m^2; got shape "
                         f"{inertia.shape}")
    require(inertia, "box_impact inertia", lo=0.0, lo_open=True, unit="kg m^2")
    R, hit, inverse_inertia = _box_state(orientation, tilt, width, height, depth, inertia)
    out = _vertex_impact(hit.r, mass, inverse_inertia, velocity, spin, friction, restitution, law, R, hit.tied,
                         from_rest)
    return eqx.tree_at(lambda b: b.flags, out, combine(out.flags, flag_if(
        _asymmetric(R, velocity, spin), Flag.FLAT_LANDING_WITH_MOTION)))


@jit
def _asymmetric(R, velocity, spin):
    """Whether the motion breaks the mirror symmetry about a level body axis (an edge or a face strikes): G's
    velocity along it, or spin across it."""
    velocity, spin = jnp.asarray(velocity, R.dtype), jnp.asarray(spin, R.dtype)
    tol = 64 * jnp.finfo(R.dtype).eps
    level = jnp.abs(R[1]) < tol
    along = jnp.abs(velocity @ R) > tol * jnp.linalg.norm(velocity)
    across = jnp.linalg.norm(jnp.cross(spin[None, :], R.T), axis=-1) > tol * jnp.linalg.norm(spin)
    return jnp.any(level & (along | across))
