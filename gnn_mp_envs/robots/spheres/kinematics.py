"""Forward kinematics and motion bounds of the sphere checker, compiled (numba,
:func:`~gnn_mp_envs.utils.compiled.jit`).

The kernel (:mod:`gnn_mp_envs.robots.spheres.kernel`) places a link's spheres by its frame
(:func:`forward_kinematics`) and skips states of an edge where certified bounds vouch for them: how
far any sphere of a link (or of a self pair, relative to each other) moves per state anywhere
(:func:`motion_bounds`), how fast it moves at a tested state (:func:`velocities`, :func:`rate`) and
how fast that speed can change; :func:`states_clear` turns a clearance into states. Arrays describe
the robot as :class:`~gnn_mp_envs.robots.spheres.checker.SphereChecker` builds it: per link its
parent (-1: the root), its joint's origin (``origin_r``, ``origin_t``), kind (0 fixed, 1 revolute,
2 prismatic, :mod:`gnn_mp_envs.robots.urdf`), axis, and the state coordinate that moves it
(``q_index``; -1: held at ``q_fixed``).
"""

from __future__ import annotations

import math

import numpy as np

from gnn_mp_envs.robots.urdf import FIXED, PRISMATIC, REVOLUTE
from gnn_mp_envs.utils.compiled import jit

#: Returned by :func:`states_clear` where nothing moves: as good as unbounded.
UNBOUNDED = 1e300
#: Rounds a bound of states slightly down (far above the rounding of its terms).
ROUND_DOWN = 1.0 - 1e-12


@jit
def forward_kinematics(q, parent, origin_r, origin_t, kind, axis, q_index, q_fixed, rot, trans):
    """Link frames ``rot[l]``, ``trans[l]`` (world) at configuration ``q``: each link's parent frame
    times its joint's origin, then the joint's rotation about (translation along) its axis."""
    for link in range(parent.shape[0]):
        p = parent[link]
        if p < 0:
            for i in range(3):
                for j in range(3):
                    rot[link, i, j] = 1.0 if i == j else 0.0
                trans[link, i] = 0.0
            continue
        v = q[q_index[link]] if q_index[link] >= 0 else q_fixed[link]
        # parent * origin (an identity origin rotation: the parent's, the same floats without the products)
        plain = (origin_r[link, 0, 0] == 1.0 and origin_r[link, 1, 1] == 1.0 and origin_r[link, 2, 2] == 1.0
                 and origin_r[link, 0, 1] == 0.0 and origin_r[link, 0, 2] == 0.0 and origin_r[link, 1, 0] == 0.0
                 and origin_r[link, 1, 2] == 0.0 and origin_r[link, 2, 0] == 0.0 and origin_r[link, 2, 1] == 0.0)
        for i in range(3):
            acc = trans[p, i]
            for k in range(3):
                acc += rot[p, i, k] * origin_t[link, k]
            trans[link, i] = acc
            if plain:
                for j in range(3):
                    rot[link, i, j] = rot[p, i, j]
                continue
            for j in range(3):
                acc = 0.0
                for k in range(3):
                    acc += rot[p, i, k] * origin_r[link, k, j]
                rot[link, i, j] = acc
        if kind[link] == REVOLUTE and axis[link, 0] == 0.0 and axis[link, 1] == 0.0 and axis[link, 2] == 1.0:
            # revolute about z: Rodrigues' matrix below with its zero terms dropped (the same floats)
            c, s = math.cos(v), math.sin(v)
            m22 = (1.0 - c) + c
            for i in range(3):
                a0, a1, a2 = rot[link, i, 0], rot[link, i, 1], rot[link, i, 2]
                rot[link, i, 0] = a0 * c + a1 * s
                rot[link, i, 1] = a0 * -s + a1 * c
                rot[link, i, 2] = a2 * m22
        elif kind[link] == REVOLUTE:        # times Rodrigues(axis, v)
            x, y, z = axis[link, 0], axis[link, 1], axis[link, 2]
            c, s = math.cos(v), math.sin(v)
            t = 1.0 - c
            m00, m01, m02 = t * x * x + c, t * x * y - s * z, t * x * z + s * y
            m10, m11, m12 = t * x * y + s * z, t * y * y + c, t * y * z - s * x
            m20, m21, m22 = t * x * z - s * y, t * y * z + s * x, t * z * z + c
            for i in range(3):
                a0, a1, a2 = rot[link, i, 0], rot[link, i, 1], rot[link, i, 2]
                rot[link, i, 0] = a0 * m00 + a1 * m10 + a2 * m20
                rot[link, i, 1] = a0 * m01 + a1 * m11 + a2 * m21
                rot[link, i, 2] = a0 * m02 + a1 * m12 + a2 * m22
        elif kind[link] == PRISMATIC:       # translate along the (rotated) axis
            for i in range(3):
                acc = 0.0
                for k in range(3):
                    acc += rot[link, i, k] * axis[link, k]
                trans[link, i] += v * acc


@jit
def velocities(a, b, n, parent, kind, axis, q_index, rot, trans, omega, vel):
    """Per link, at the configuration whose frames ``rot``, ``trans`` hold: the angular velocity
    ``omega[l]`` and the velocity ``vel[l]`` of the frame's origin for one state's step ``(b - a) / n``
    of the edge (world axes; per state, not per second)."""
    for link in range(parent.shape[0]):
        p = parent[link]
        if p < 0:
            for i in range(3):
                omega[link, i] = 0.0
                vel[link, i] = 0.0
            continue
        wx, wy, wz = omega[p, 0], omega[p, 1], omega[p, 2]
        dx, dy, dz = trans[link, 0] - trans[p, 0], trans[link, 1] - trans[p, 1], trans[link, 2] - trans[p, 2]
        vel[link, 0] = vel[p, 0] + wy * dz - wz * dy
        vel[link, 1] = vel[p, 1] + wz * dx - wx * dz
        vel[link, 2] = vel[p, 2] + wx * dy - wy * dx
        omega[link, 0], omega[link, 1], omega[link, 2] = wx, wy, wz
        j = q_index[link]
        if j >= 0 and kind[link] != FIXED:
            step = (b[j] - a[j]) / n
            for i in range(3):
                world = (rot[link, i, 0] * axis[link, 0] + rot[link, i, 1] * axis[link, 1]
                         + rot[link, i, 2] * axis[link, 2])
                if kind[link] == REVOLUTE:
                    omega[link, i] += step * world
                else:
                    vel[link, i] += step * world


@jit
def motion_bounds(a, b, n, reach, delta, curve):
    """Per row of ``reach`` (a link, or a self pair's relative motion), for one state's step
    ``(b - a) / n``: ``delta``, how far any of its spheres moves at most anywhere (the joints' steps
    times their levers), and ``curve``, how much the speed of any of its points changes at most per
    state. A point's velocity is ``sum_j dq_j a_j x (p - o_j)``; along the edge each axis ``a_j``
    turns at most by the steps of the joints above it and each ``p - o_j`` changes at most by
    ``sum_j dq_j reach_j``, so the change is at most ``3 (sum_j dq_j) delta`` over the joints that move it."""
    steps = np.empty(reach.shape[1])
    for j in range(reach.shape[1]):
        steps[j] = abs(b[j] - a[j]) / n
    for r in range(reach.shape[0]):
        acc = 0.0
        turn = 0.0
        for j in range(reach.shape[1]):
            if reach[r, j] > 0.0:
                acc += steps[j] * reach[r, j]
                turn += steps[j]
        delta[r] = acc
        curve[r] = 3.0 * turn * acc


@jit(inline=True)
def rate(moving, frame, node, nodes, rot, trans, omega, vel):
    """How fast (per state) the points of the sphere ``node`` of link ``moving`` move at most at this
    configuration, relative to link ``frame`` (-1: the world): the speed of its centre plus the
    relative turn rate times its radius (from :func:`velocities`)."""
    x, y, z = nodes[node, 0], nodes[node, 1], nodes[node, 2]
    ux = rot[moving, 0, 0] * x + rot[moving, 0, 1] * y + rot[moving, 0, 2] * z   # centre from the origin
    uy = rot[moving, 1, 0] * x + rot[moving, 1, 1] * y + rot[moving, 1, 2] * z
    uz = rot[moving, 2, 0] * x + rot[moving, 2, 1] * y + rot[moving, 2, 2] * z
    wx, wy, wz = omega[moving, 0], omega[moving, 1], omega[moving, 2]
    vx = vel[moving, 0] + wy * uz - wz * uy
    vy = vel[moving, 1] + wz * ux - wx * uz
    vz = vel[moving, 2] + wx * uy - wy * ux
    if frame >= 0:          # less the velocity of the point fixed to ``frame`` at the centre
        fx, fy, fz = omega[frame, 0], omega[frame, 1], omega[frame, 2]
        rx = trans[moving, 0] + ux - trans[frame, 0]
        ry = trans[moving, 1] + uy - trans[frame, 1]
        rz = trans[moving, 2] + uz - trans[frame, 2]
        vx -= vel[frame, 0] + fy * rz - fz * ry
        vy -= vel[frame, 1] + fz * rx - fx * rz
        vz -= vel[frame, 2] + fx * ry - fy * rx
        wx, wy, wz = wx - fx, wy - fy, wz - fz
    return math.sqrt(vx * vx + vy * vy + vz * vz) + math.sqrt(wx * wx + wy * wy + wz * wz) * nodes[node, 3]


@jit(inline=True)
def states_clear(gap, rate, curve, delta):
    """How many states away (either way along the edge, real-valued) spheres at least ``gap`` from
    everything stay clear, that is, states nearer than it are free: the larger of ``gap / delta``
    (spheres move at most ``delta`` per state anywhere) and the root of ``rate s + curve s^2 / 2 =
    gap`` (they move at ``rate`` per state here, and that speed changes by at most ``curve`` per
    state; ``rate = curve = 0``: no such bound). Slightly rounded down; :data:`UNBOUNDED` where nothing moves."""
    if gap <= 0.0:
        return gap
    if delta <= 0.0:
        return UNBOUNDED
    out = gap / delta
    den = rate + math.sqrt(rate * rate + 2.0 * curve * gap)
    if den > 0.0:
        quadratic = 2.0 * gap / den
        out = quadratic if quadratic > out else out
    return out * ROUND_DOWN
