"""Sphere models that cover a robot's collision geometry: made from the mesh files, checked by
the same code that tests them.

pybullet collides the convex hull ``H`` of each collision mesh (of each object of an OBJ file)
inflated by its collision margin (:data:`BULLET_MARGIN`, 1 mm), and the planner treats a contact
closer than the robot's padding as a collision too. A sphere model for a margin ``m`` (the two
together) is a set of spheres whose union contains ``H ⊕ m`` (``H`` grown by ``m`` in every
direction) and lies inside ``H ⊕ (m + overshoot)``: conservative, and at most ``overshoot`` more
so than the shape it stands for.

How (per hull): points are drawn on the boundary of ``H ⊕ m`` (its flat faces, the cylinder
strips along the hull's edges and the sphere caps at its vertices) and inside ``H``. Candidate
spheres are centred inside ``H`` (on the surface and at a geometric series of depths below it),
each with the largest radius that keeps it inside ``H ⊕ (m + overshoot)``: ``depth + m +
overshoot``, where ``depth`` is the centre's distance to ``H``'s boundary (exact for a convex
polytope). A greedy set cover picks spheres until every point is covered (the points a little
beyond the margin, so that the union's dips between them stay outside it); a
denser independent sample then checks the union and adds spheres where a point is still out, until
none is. Each link's spheres are then grouped (k-means of their centres) under bounding spheres,
and those under one bounding sphere of the link (:func:`build_tree`): the coarse levels the checker tests first.

``python -m tools.spherize`` writes the shipped models (:mod:`gnn_mp_envs.robots.spheres.model`);
``tests/test_spheres.py`` re-checks their coverage from the mesh files with :func:`coverage_gaps`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.cluster.vq import kmeans2
from scipy.spatial import ConvexHull, cKDTree

from gnn_mp_envs.robots.urdf import Collision, URDFRobot, mesh_parts, mesh_triangles

#: pybullet's collision margin of a URDF mesh's convex hull (m): its contacts report the hull's
#: distance minus this (measured on the Panda's links against spheres and boxes).
BULLET_MARGIN = 0.001
#: The cover is checked on samples, so the union may dip between them: it contains ``H ⊕ (margin -
#: COVER_TOLERANCE)`` (dips measured on the shipped models reach 0.2 mm). Every shipped model keeps
#: ``margin - COVER_TOLERANCE`` above pybullet's margin, so it is conservative against pybullet's
#: own check; ``tests/test_spheres.py`` checks the coverage at this tolerance.
COVER_TOLERANCE = 0.2e-3
#: Depths (m) below each candidate surface point at which candidate centres are tried.
CANDIDATE_DEPTHS = (0.0, 0.001, 0.002, 0.004, 0.008, 0.016, 0.032, 0.064, 0.128)


@dataclass
class Hull:
    """A convex hull: its vertices, its outward face planes ``n . x + b <= 0`` and its boundary
    triangles with their outward normals."""

    points: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray
    triangles: np.ndarray
    triangle_normals: np.ndarray

    @classmethod
    def of(cls, points: np.ndarray) -> "Hull":
        hull = ConvexHull(np.asarray(points, dtype=np.float64))
        # one plane per facet (coplanar triangles share it): the depth test is over planes
        planes = np.unique(np.round(hull.equations, 12), axis=0)
        return cls(hull.points[hull.vertices], planes[:, :3], planes[:, 3], hull.points[hull.simplices],
                   hull.equations[:, :3])

    def depth(self, x: np.ndarray) -> np.ndarray:
        """Distance of each row of ``x`` to the boundary, positive inside (outside: a lower bound
        of minus the distance to the hull, exact where one face is nearest)."""
        return -(np.asarray(x) @ self.normals.T + self.offsets).max(axis=-1)


def _clip_slab(triangle: np.ndarray, axis: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """The part of a triangle between the planes ``axis . x = lo`` and ``= hi`` (its polygon's corners)."""
    poly = list(triangle)
    for sign, bound in ((1.0, lo), (-1.0, -hi)):
        out = []
        for k in range(len(poly)):
            a, b = poly[k], poly[(k + 1) % len(poly)]
            da, db = sign * float(a @ axis) - bound, sign * float(b @ axis) - bound
            if da >= 0:
                out.append(a)
            if (da >= 0) != (db >= 0):
                out.append(a + (da / (da - db)) * (b - a))
        poly = out
        if not poly:
            break
    return np.array(poly).reshape(-1, 3)


def concave_hulls(triangles: np.ndarray, slabs: int = 12) -> list[Hull]:
    """Convex hulls whose union contains a closed (concave) mesh: the mesh cut into ``slabs`` slabs
    along its longest principal axis, each slab's triangles clipped to it and their hull taken. The
    part of the solid in a slab lies in the hull of its boundary there (the clipped surface holds
    the cut's outline), so the union contains the solid; thin slabs keep each hull close to it."""
    pts = triangles.reshape(-1, 3)
    centred = pts - pts.mean(0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    z = pts @ axis
    edges = np.linspace(z.min(), z.max(), slabs + 1)
    hulls = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        tz = triangles @ axis
        near = (tz.max(axis=1) >= lo) & (tz.min(axis=1) <= hi)
        part = [_clip_slab(t, axis, lo, hi) for t in triangles[near]]
        part = np.concatenate([p for p in part if len(p)]) if part else np.zeros((0, 3))
        if len(part) >= 4:
            try:
                hulls.append(Hull.of(part))
            except Exception:          # a degenerate (flat) slab: skip only if it is not needed
                if np.ptp(part @ axis) > 1e-9:
                    raise
    return hulls


def hulls_of(collision: Collision) -> list[Hull]:
    """The convex hulls pybullet collides for one collision element (cylinders: a prism of 64
    sides around it, so containing it; concave meshes: slab hulls that together contain the solid,
    :func:`concave_hulls`; spheres are handled apart by the caller)."""
    if collision.concave:
        return concave_hulls(mesh_triangles(collision))
    if collision.kind == "cylinder":
        radius, length = collision.size
        sides = 64
        a = np.arange(sides) * 2 * math.pi / sides
        ring = np.stack([np.cos(a), np.sin(a)], 1) * radius / math.cos(math.pi / sides)
        pts = np.concatenate([np.c_[ring, np.full(sides, z)] for z in (-length / 2, length / 2)])
        return [Hull.of(pts @ collision.rotation.T + collision.translation)]
    return [Hull.of(p) for p in mesh_parts(collision) if len(p) >= 4]


# ---------------------------------------------------------------------- boundary samples
def _fibonacci_directions(n: int) -> np.ndarray:
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = k * math.pi * (3 - math.sqrt(5))
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def _triangle_lattice(t: np.ndarray, spacing: float) -> np.ndarray:
    """Points of a triangular lattice of side ``spacing`` inside triangle ``t`` (3 x 3), plus its
    corners and points along its edges ``spacing`` apart (so a sliver narrower than the lattice
    still gets points)."""
    e1 = t[1] - t[0]
    length = float(np.linalg.norm(e1))
    n = np.cross(e1, t[2] - t[0])
    area2 = float(np.linalg.norm(n))
    edges = [t[a] + np.linspace(0, 1, max(2, int(math.ceil(np.linalg.norm(t[b] - t[a]) / spacing)) + 1))[:, None]
             * (t[b] - t[a]) for a, b in ((0, 1), (1, 2), (2, 0))]
    if area2 < 1e-18 or length < 1e-12:
        return np.concatenate(edges)
    e1 = e1 / length
    e2 = np.cross(n / area2, e1)
    xy = np.stack([(t - t[0]) @ e1, (t - t[0]) @ e2], 1)
    lo, hi = xy.min(0), xy.max(0)
    rows = np.arange(lo[1], hi[1] + spacing, spacing * math.sqrt(3) / 2)
    grid = [np.stack([np.arange(lo[0] + (k % 2) * spacing / 2, hi[0] + spacing, spacing), np.full_like(
        np.arange(lo[0] + (k % 2) * spacing / 2, hi[0] + spacing, spacing), y)], 1) for k, y in enumerate(rows)]
    g = np.concatenate(grid)
    # barycentric inside test in the triangle's plane
    a, b, c = xy
    m = np.array([[b[0] - a[0], c[0] - a[0]], [b[1] - a[1], c[1] - a[1]]])
    uv = np.linalg.solve(m, (g - a).T).T
    inside = (uv[:, 0] >= -1e-9) & (uv[:, 1] >= -1e-9) & (uv.sum(1) <= 1 + 1e-9)
    g = g[inside]
    return np.concatenate([t[0] + g[:, :1] * e1 + g[:, 1:] * e2] + edges)


def boundary_samples(hull: Hull, margin: float, spacing: float, rng: np.random.Generator | None,
                     faces_only: bool = False, faces: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points on the boundary of ``hull ⊕ margin`` about ``spacing`` apart, the point of the hull
    each stands over and the outward unit normal there (``point = base + margin * normal``): on the
    faces at random (``rng``) or on a regular grid (``rng=None``); with ``faces_only``, only the
    flat parts (over the hull's faces); without ``faces``, only the rounded parts (over the hull's
    edges and vertices)."""
    tri = hull.triangles
    if not faces:
        base, normal = [np.zeros((0, 3))], [np.zeros((0, 3))]
    elif rng is None:
        # a triangular lattice on each triangle: no point of it farther than about spacing / sqrt(3)
        # from a sample (random points leave holes of about twice their spacing)
        base_f, which_f = [], []
        for f, t in enumerate(tri):
            pts = _triangle_lattice(t, spacing)
            base_f.append(pts)
            which_f.append(np.full(len(pts), f))
        base = [np.concatenate(base_f)]
        which = np.concatenate(which_f)
    else:
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        n_face = max(1, int(area.sum() / spacing ** 2))
        which = rng.choice(len(tri), size=n_face, p=area / area.sum())
        u, v = rng.random(n_face), rng.random(n_face)
        flip = u + v > 1
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
        t = tri[which]
        base = [t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])]
    if faces:
        normal = [hull.triangle_normals[which]]
    if faces_only:
        return base[0] + margin * normal[0], base[0], normal[0]
    # edges between non-coplanar triangles: the cylinder strip between the two face normals
    edges: dict[tuple[int, int], list[int]] = {}
    key = {tuple(p): i for i, p in enumerate(hull.points)}
    for f, corners in enumerate(tri):
        ids = [key[tuple(c)] for c in corners]
        for a, b in ((ids[0], ids[1]), (ids[1], ids[2]), (ids[2], ids[0])):
            edges.setdefault((min(a, b), max(a, b)), []).append(f)
    for (a, b), faces in edges.items():
        if len(faces) != 2:
            continue
        n1, n2 = hull.triangle_normals[faces[0]], hull.triangle_normals[faces[1]]
        angle = math.acos(max(-1.0, min(1.0, float(n1 @ n2))))
        if angle < 1e-6:
            continue
        pa, pb = hull.points[a], hull.points[b]
        along = max(2, int(math.ceil(np.linalg.norm(pb - pa) / spacing)) + 1)
        across = max(2, int(math.ceil(margin * angle / spacing)) + 1)
        s = np.linspace(0, 1, along)[:, None]
        w = np.linspace(0, 1, across)
        dirs = (np.sin((1 - w) * angle)[:, None] * n1 + np.sin(w * angle)[:, None] * n2) / math.sin(angle)
        pts = pa + s * (pb - pa)
        base.append(np.repeat(pts, across, axis=0))
        normal.append(np.tile(dirs, (along, 1)))
    # vertex caps: directions whose support point is the vertex
    dirs = _fibonacci_directions(int(np.clip(16 * math.pi * margin ** 2 / spacing ** 2, 2000, 50000)))
    support = np.argmax(dirs @ hull.points.T, axis=1)
    base.append(hull.points[support])
    normal.append(dirs)
    base_all = np.concatenate(base)
    normal_all = np.concatenate(normal)
    normal_all /= np.linalg.norm(normal_all, axis=1, keepdims=True)
    return base_all + margin * normal_all, base_all, normal_all


def interior_samples(hull: Hull, spacing: float) -> np.ndarray:
    """Grid points inside the hull, ``spacing`` apart."""
    lo, hi = hull.points.min(0), hull.points.max(0)
    axes = [np.arange(a + spacing / 2, b, spacing) for a, b in zip(lo, hi)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return grid[hull.depth(grid) > 0] if len(grid) else grid


# ---------------------------------------------------------------------- cover
def union_depth(hulls: list[Hull], x: np.ndarray) -> np.ndarray:
    """A lower bound of each point's depth in the union of ``hulls``: its largest depth in one of them
    (a ball inside one hull is inside the union)."""
    return np.max([h.depth(x) for h in hulls], axis=0)


def _candidates(hull: Hull, margin: float, overshoot: float, spacing: float, rng: np.random.Generator,
                union: list[Hull] | None = None) -> np.ndarray:
    """Candidate spheres ``(k, 4)`` inside ``hull ⊕ (margin + overshoot)``: centres at the hull's
    vertices and at surface points pushed in by each of :data:`CANDIDATE_DEPTHS` (deeper ones
    sparser: a sphere's cap on the boundary widens with its depth), radius ``depth + margin +
    overshoot``."""
    # on the surface: every kind of boundary point (faces, edges, vertices), for sharp features
    centres = [hull.points, np.unique(boundary_samples(hull, margin, spacing, rng)[1], axis=0)]
    for t in CANDIDATE_DEPTHS[1:]:
        cap = math.sqrt(2 * (t + margin) * overshoot)
        _, base, normal = boundary_samples(hull, margin, max(spacing, cap / 2), rng, faces_only=True)
        centres.append(base - t * normal)
    # the deepest point along each inward normal (on the medial axis of round links)
    _, base, normal = boundary_samples(hull, margin, 4 * spacing, rng, faces_only=True)
    extent = float(np.linalg.norm(hull.points.max(0) - hull.points.min(0)))
    ts = np.linspace(0.0, extent, 41)
    ray = base[:, None, :] - ts[None, :, None] * normal[:, None, :]
    best = hull.depth(ray.reshape(-1, 3)).reshape(len(base), len(ts)).argmax(axis=1)
    centres.append(ray[np.arange(len(base)), best])
    c = np.concatenate(centres)
    d = union_depth(union or [hull], c)
    keep = d >= -1e-7           # the surface itself (vertices, edges) up to rounding
    c, d = c[keep], np.maximum(d[keep], 0.0)
    return np.c_[c, d + margin + overshoot]


def inside_union(points: np.ndarray, spheres: np.ndarray) -> np.ndarray:
    """Whether each point lies in at least one of ``spheres`` (``(k, 4)``: centre, radius).

    Exact, by one nearest-neighbour query: with ``R`` the largest radius, a sphere ``(c, r)``
    becomes the 4-D point ``(c, sqrt(R^2 - r^2))`` and a point ``p`` the point ``(p, 0)``; then
    ``|p - c|^2 - r^2 = |p' - c'|^2 - R^2``, so ``p`` is inside some sphere exactly when its 4-D
    nearest neighbour is within ``R``."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if not len(spheres) or not len(points):
        return np.zeros(len(points), dtype=bool)
    big = float(spheres[:, 3].max())
    lifted = np.c_[spheres[:, :3], np.sqrt(np.maximum(big ** 2 - spheres[:, 3] ** 2, 0.0))]
    d, i = cKDTree(lifted).query(np.c_[points, np.zeros(len(points))], k=1)
    # decide on the power distance itself, not on the rounded 4-D one
    return ((points - spheres[i, :3]) ** 2).sum(1) <= spheres[i, 3] ** 2


def _greedy_cover(points: np.ndarray, candidates: np.ndarray) -> list[int]:
    """Indices of candidates covering every point, greedy by count (lazy re-evaluation)."""
    import heapq
    lists = cKDTree(points).query_ball_point(candidates[:, :3], candidates[:, 3])
    lists = [np.asarray(x, dtype=np.int64) for x in lists]
    covered = np.zeros(len(points), dtype=bool)
    heap = [(-len(x), i) for i, x in enumerate(lists) if len(x)]
    heapq.heapify(heap)
    chosen: list[int] = []
    left = len(points)
    while left and heap:
        _, i = heapq.heappop(heap)
        gain = int((~covered[lists[i]]).sum())
        if gain == 0:
            continue
        if heap and gain < -heap[0][0]:
            heapq.heappush(heap, (-gain, i))
            continue
        chosen.append(i)
        covered[lists[i]] = True
        left -= gain
    if left:
        raise RuntimeError(f"{left} sample points are covered by no candidate sphere")
    return chosen


def cover_hull(hull: Hull, margin: float, overshoot: float, spacing: float, seed: int = 0,
               union: list[Hull] | None = None, sag: float = 0.1e-3, rounds: int = 30) -> np.ndarray:
    """Spheres ``(k, 4)`` whose union contains ``hull ⊕ margin`` and lies inside ``hull ⊕ (margin
    + overshoot)``.

    The greedy cover is of boundary points of ``hull ⊕ (margin + sag)`` about ``spacing`` apart,
    so that the union's dips between sample points (well under ``sag`` for spheres of a few
    millimetres and more) stay outside ``hull ⊕ margin``; candidates reach ``overshoot`` beyond
    ``margin``. Then a denser independent sample of ``hull ⊕ (margin - COVER_TOLERANCE / 2)`` and
    the interior are checked, and spheres added where a point is out, until none is."""
    rng = np.random.default_rng(seed)
    sag = min(sag, overshoot / 3)
    target = margin + sag
    # a sphere on the surface (radius margin + overshoot) reaches the sampled boundary this far aside:
    # samples and candidates must be closer than that, or small overshoots leave points uncovered
    spacing = min(spacing, 0.7 * math.sqrt((margin + overshoot) ** 2 - target ** 2))
    points = boundary_samples(hull, target, spacing, None)[0]
    candidates = _candidates(hull, margin, overshoot, spacing, rng, union)
    spheres = candidates[_greedy_cover(points, candidates)]
    interior = interior_samples(hull, max(4 * spacing, 0.004))
    for r in range(rounds):
        # checked half way into the stated tolerance (shallower dips are within it), at most ~600k points
        tri = hull.triangles
        area = 0.5 * float(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())
        check, check_base, _ = boundary_samples(hull, margin - COVER_TOLERANCE / 2,
                                                max(spacing / 2, math.sqrt(area / 600_000)),
                                                np.random.default_rng([seed, r + 1]))
        out = ~inside_union(check, spheres)
        inner = interior[~inside_union(interior, spheres)]
        if not out.any() and not len(inner):
            return spheres
        if len(inner):
            spheres = np.concatenate([spheres, candidates[_greedy_cover(inner, candidates)]])
        if out.any():
            extra = np.unique(check_base[out], axis=0)
            extra_c = np.c_[extra, np.maximum(union_depth(union or [hull], extra), 0.0) + margin + overshoot]
            spheres = np.concatenate([spheres, extra_c[_greedy_cover(check[out], extra_c)]])
    raise RuntimeError(f"spheres still leave points of the hull uncovered after {rounds} repair rounds")


# ---------------------------------------------------------------------- levels
def bounding_sphere(spheres: np.ndarray) -> np.ndarray:
    """A sphere containing every sphere of ``spheres`` (centre: the middle of their extents'
    box, then a few steps toward the farthest one)."""
    lo = (spheres[:, :3] - spheres[:, 3:]).min(0)
    hi = (spheres[:, :3] + spheres[:, 3:]).max(0)
    c = (lo + hi) / 2
    for k in range(50):
        reach = np.linalg.norm(spheres[:, :3] - c, axis=1) + spheres[:, 3]
        far = int(np.argmax(reach))
        d = spheres[far, :3] - c
        n = np.linalg.norm(d)
        if n < 1e-12:
            break
        c = c + d / n * (reach[far] - reach.mean()) * 0.5 / (k + 1)
    r = float((np.linalg.norm(spheres[:, :3] - c, axis=1) + spheres[:, 3]).max()) * (1 + 1e-9)
    return np.r_[c, r]


def group_spheres(spheres: np.ndarray, size: int = 12, seed: int = 0) -> tuple[np.ndarray, list[np.ndarray]]:
    """Fine spheres grouped by k-means of their centres (about ``size`` per group): the groups'
    bounding spheres ``(g, 4)`` and each group's member rows."""
    k = max(1, int(math.ceil(len(spheres) / size)))
    if k == 1:
        return bounding_sphere(spheres)[None], [np.arange(len(spheres))]
    _, label = kmeans2(spheres[:, :3], k, minit="++", seed=seed)
    members = [np.flatnonzero(label == g) for g in range(k)]
    members = [m for m in members if len(m)]
    return np.stack([bounding_sphere(spheres[m]) for m in members]), members


# ---------------------------------------------------------------------- trees
def build_tree(leaves: np.ndarray, coarse: np.ndarray | None = None, branching: int = 8, leaf_size: int = 8,
               seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A sphere tree over ``leaves`` ``(k, 4)``: nodes in breadth-first order (root first, each
    node's children consecutive), every inner node a sphere containing the leaves below it.

    With ``coarse`` (a few spheres covering the same shape more loosely), the root's children are
    one node per coarse sphere: its centre, grown to contain the leaves assigned to it (each leaf
    to the coarse sphere it sticks out of least), so that the second level is a coarse cover of the
    link; below, groups of about ``branching`` by k-means of the centres down to ``leaf_size``.
    Returns ``nodes``, ``first_child``, ``child_count``."""
    nodes: list[np.ndarray] = []
    first: list[int] = []
    count: list[int] = []
    queue: list[tuple[np.ndarray, np.ndarray | None]] = [(np.arange(len(leaves)), None)]   # (leaf rows, sphere)
    for k, (members, sphere) in enumerate(queue):
        if len(members) == 1 and sphere is None:   # a leaf: the fine sphere itself
            nodes.append(leaves[members[0]])
            first.append(0)
            count.append(0)
            continue
        nodes.append(bounding_sphere(leaves[members]) if sphere is None else sphere)
        if k == 0 and coarse is not None and len(coarse) > 1:
            out = (np.linalg.norm(leaves[:, None, :3] - coarse[None, :, :3], axis=2) + leaves[:, None, 3]
                   - coarse[None, :, 3])
            owner = out.argmin(axis=1)
            groups = []
            for g in range(len(coarse)):
                rows = np.flatnonzero(owner == g)
                if len(rows):
                    reach = float((np.linalg.norm(leaves[rows, :3] - coarse[g, :3], axis=1) + leaves[rows, 3]).max())
                    groups.append((rows, np.r_[coarse[g, :3], max(reach, coarse[g, 3]) * (1 + 1e-9)]))
        elif len(members) <= leaf_size:
            groups = [(members[i:i + 1], None) for i in range(len(members))]
        else:
            _, parts = group_spheres(leaves[members], size=max(1, len(members) // branching), seed=seed)
            groups = [(members[p], None) for p in parts]
            if len(groups) == 1:              # k-means could not split: halves along the longest axis
                axis = int(np.argmax(np.ptp(leaves[members, :3], axis=0)))
                order = members[np.argsort(leaves[members, axis], kind="stable")]
                groups = [(order[: len(order) // 2], None), (order[len(order) // 2:], None)]
        first.append(len(queue))
        count.append(len(groups))
        queue.extend(groups)
    return np.array(nodes, dtype=np.float64), np.array(first, dtype=np.int64), np.array(count, dtype=np.int64)


# ---------------------------------------------------------------------- robots
def link_geometry(robot: URDFRobot, link: str) -> tuple[list[Hull], np.ndarray]:
    """The hulls of a link's collision elements, and its sphere elements ``(k, 4)`` (exact)."""
    hulls, balls = [], []
    for col in robot.collisions.get(link, ()):
        if col.kind == "sphere":
            balls.append(np.r_[col.translation, col.size[0]])
        else:
            hulls.extend(hulls_of(col))
    return hulls, np.array(balls).reshape(-1, 4)


def spherize_link(robot: URDFRobot, link: str, margin: float, overshoot: float, spacing: float,
                  seed: int = 0) -> np.ndarray:
    """Fine spheres ``(k, 4)`` of one link (in its frame) for ``margin`` and ``overshoot``."""
    hulls, balls = link_geometry(robot, link)
    # spheres of one hull may reach into the others: the link's collision shape is their union
    parts = [cover_hull(h, margin, overshoot, spacing, seed=seed + i, union=hulls) for i, h in enumerate(hulls)]
    if len(balls):
        parts.append(np.c_[balls[:, :3], balls[:, 3] + margin])
    return np.concatenate(parts) if parts else np.zeros((0, 4))


def coverage_gaps(robot: URDFRobot, link: str, spheres: np.ndarray, margin: float, spacing: float,
                  seed: int = 12345) -> dict[str, int]:
    """Points of the link's ``hull ⊕ margin`` outside the union of ``spheres``: its hull vertices
    pushed out by ``margin`` along every direction of their normal cones, and a fresh boundary sample
    ``spacing`` apart. ``{"vertices": n_out, "surface": n_out, "checked": n}``."""
    hulls, balls = link_geometry(robot, link)
    out_v = out_s = total = 0
    rng = np.random.default_rng(seed)
    for hull in hulls:
        dirs = _fibonacci_directions(4000)
        support = np.argmax(dirs @ hull.points.T, axis=1)
        # every vertex itself, grown by the margin along the mean of its cone's directions
        vertex_points = []
        for v in range(len(hull.points)):
            cone = dirs[support == v]
            u = cone.mean(0) if len(cone) else hull.points[v] - hull.points.mean(0)
            vertex_points.append(hull.points[v] + margin * u / np.linalg.norm(u))
        vertex_points = np.concatenate([np.array(vertex_points), hull.points[support] + margin * dirs])
        surface = boundary_samples(hull, margin, spacing, rng)[0]
        out_v += int((~inside_union(vertex_points, spheres)).sum())
        out_s += int((~inside_union(surface, spheres)).sum())
        total += len(vertex_points) + len(surface)
    for ball in balls:
        pts = ball[:3] + (ball[3] + margin) * _fibonacci_directions(500)
        out_s += int((~inside_union(pts, spheres)).sum())
        total += len(pts)
    return {"vertices": out_v, "surface": out_s, "checked": total}


def max_overshoot(robot: URDFRobot, link: str, spheres: np.ndarray, margin: float) -> float:
    """How far the spheres reach beyond ``hull ⊕ margin`` at most (m), measured at each sphere's
    farthest point from the nearest hull: ``r - margin - depth(centre)`` for centres inside a hull."""
    hulls, balls = link_geometry(robot, link)
    worst = np.full(len(spheres), np.inf)
    for hull in hulls:
        worst = np.minimum(worst, spheres[:, 3] - margin - hull.depth(spheres[:, :3]))
    for ball in balls:
        inside = ball[3] - np.linalg.norm(spheres[:, :3] - ball[:3], axis=1)
        worst = np.minimum(worst, spheres[:, 3] - margin - inside)
    return float(worst.max()) if len(worst) else 0.0
