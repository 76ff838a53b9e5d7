"""Exact first-hit ray casting of a synthetic scene (numba): a heightfield ground with curbs, and primitives.

Primitives live in their own local frame (`local = rot @ (world - center)`):
- BOX: half extents (a, b, c); optional rounding: intersected with the ellipsoid of semi-axes (sa a, sb b,
  sc c) given in size[3:6] (0 = sharp box).
- ELLIPSOID: semi-axes (a, b, c).
- CYLINDER: axis local z, radius a, half height c; size[3] > 0 makes it a tube with that inner radius
  (bicycle wheels).
Primitives are grouped into objects with a bounding sphere; objects are binned by the azimuth sector their
sphere covers and sorted by nearest distance in each bin, so a ray tests only the few objects in its sector
and stops once the next object is farther than its best hit.

The ground is z = h(u, v) in road coordinates (u along the road, from the ray origin's foot; v across it, from the
road's centre line), region by region (road,
sidewalk, terrain) with curb steps between them. A ray is split at the region borders it crosses; inside a
piece the smooth height is sphere-traced with a Lipschitz bound (never overshoots, so the first hit is
found); at a border a ray below the next region's surface hits the vertical curb face.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

BOX, ELLIPSOID, CYLINDER = 0, 1, 2
NO_HIT, GROUND_HIT = -1, -2
ROAD, SIDEWALK, TERRAIN = 1, 2, 3

# Indices into the ground parameter vector.
G_COS, G_SIN, G_VEGO, G_W, G_S, G_CURB, G_CROSS, G_XC, G_WC = 0, 1, 2, 3, 4, 5, 6, 7, 8
G_CROWN, G_KU, G_TV, G_Z0, G_TERR, G_L_ROAD, G_L_WALK, G_L_TERR, G_ZMIN, G_ZMAX = 9, 10, 11, 12, 13, 14, 15, 16, 17, 18
G_TU = 19  # slope along u: 0 in a scene's own frame; a drive's scan seen from farther along the road takes KU u there
N_GROUND_PARAMS = 20

_EPS_HIT = 2e-3  # sphere tracing stops this close to the surface (m), well below the range noise
_MAX_STEPS = 96
_ORDER_SLACK = 0.15  # lasers fire up to 0.06 m from the eye height the bins are sorted for; twice that, plus margin


@nb.njit(cache=True)
def ground_region(gp: np.ndarray, u: float, v: float) -> int:
    """ROAD, SIDEWALK or TERRAIN at road coordinates (u, v)."""
    av = abs(v)
    du = abs(u - gp[G_XC])
    cross = gp[G_CROSS] > 0.5
    if av < gp[G_W] or (cross and du < gp[G_WC]):
        return ROAD
    if av < gp[G_W] + gp[G_S] or (cross and du < gp[G_WC] + gp[G_S]):
        return SIDEWALK
    return TERRAIN


@nb.njit(cache=True)
def ground_height(gp: np.ndarray, bumps: np.ndarray, waves: np.ndarray, u: float, v: float, region: int) -> float:
    """Ground height at road coordinates (u, v) as the surface of `region` (smooth inside a region)."""
    h = gp[G_Z0] + 0.5 * gp[G_KU] * u * u + gp[G_TV] * v + gp[G_TU] * u
    for k in range(bumps.shape[0]):
        du = u - bumps[k, 0]
        dv = v - bumps[k, 1]
        q = (du * du + dv * dv) / (bumps[k, 3] * bumps[k, 3])
        if q < 1.0:
            h += bumps[k, 2] * (1.0 - q) * (1.0 - q)
    if region == ROAD:
        x = v / gp[G_W]
        if x * x < 1.0:
            h += gp[G_CROWN] * (1.0 - x * x)
    elif region == SIDEWALK:
        h += gp[G_CURB]
    else:
        h += gp[G_CURB] + gp[G_TERR]
        for k in range(waves.shape[0]):
            h += waves[k, 3] * math.sin(waves[k, 0] * u + waves[k, 1] * v + waves[k, 2])
    return h


@nb.njit(cache=True)
def ground_height_at(gp: np.ndarray, bumps: np.ndarray, waves: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Ground height under each sensor-frame (x, y) of `xy` (N x 2)."""
    out = np.empty(xy.shape[0])
    c, s = gp[G_COS], gp[G_SIN]
    for i in range(xy.shape[0]):
        u = c * xy[i, 0] + s * xy[i, 1]
        v = -s * xy[i, 0] + c * xy[i, 1] + gp[G_VEGO]
        out[i] = ground_height(gp, bumps, waves, u, v, ground_region(gp, u, v))
    return out


@nb.njit(cache=True)
def _region_lipschitz(gp: np.ndarray, region: int) -> float:
    if region == ROAD:
        return gp[G_L_ROAD]
    if region == SIDEWALK:
        return gp[G_L_WALK]
    return gp[G_L_TERR]


@nb.njit(cache=True)
def _trace_ground(gp, bumps, waves, oz, v0, dz, du, dv, t_end):
    """First ground hit of the ray (u, v, z) = (t du, v0 + t dv, oz + t dz) before t_end.

    Returns (t, region, curb_normal_u, curb_normal_v); t = inf for no hit; the curb normal is (0, 0) for a
    hit on a surface.
    """
    inf = np.inf
    hxy = math.sqrt(du * du + dv * dv)
    zmax = gp[G_ZMAX]
    zmin = gp[G_ZMIN]
    if dz >= 0.0 and oz > zmax:
        return inf, 0, 0.0, 0.0
    t0 = 0.0
    if oz > zmax:
        t0 = (oz - zmax) / (-dz)
    t1 = t_end
    if dz < 0.0:
        t1 = min(t1, (oz - zmin) / (-dz) + 1e-3)
    if t0 >= t1:
        return inf, 0, 0.0, 0.0
    # Region borders crossed in (t0, t1): lines v = const and (with a cross street) u = const.
    cuts = np.empty(8)
    kind = np.empty(8, dtype=np.int64)
    n = 0
    w, s = gp[G_W], gp[G_S]
    if abs(dv) > 1e-12:
        for line in (w, -w, w + s, -w - s):
            tc = (line - v0) / dv
            if t0 < tc < t1:
                cuts[n] = tc
                kind[n] = 1
                n += 1
    if gp[G_CROSS] > 0.5 and abs(du) > 1e-12:
        xc, wc = gp[G_XC], gp[G_WC]
        for line in (xc + wc, xc - wc, xc + wc + s, xc - wc - s):
            tc = line / du
            if t0 < tc < t1:
                cuts[n] = tc
                kind[n] = 0
                n += 1
    for i in range(1, n):  # insertion sort, at most 8 entries
        j = i
        while j > 0 and cuts[j - 1] > cuts[j]:
            cuts[j - 1], cuts[j] = cuts[j], cuts[j - 1]
            kind[j - 1], kind[j] = kind[j], kind[j - 1]
            j -= 1
    a = t0
    tm = a + 1e-6
    region = ground_region(gp, tm * du, v0 + tm * dv)
    for piece in range(n + 1):
        b = cuts[piece] if piece < n else t1
        lip = abs(dz) + _region_lipschitz(gp, region) * hxy + 1e-9
        t = a
        f = np.inf
        for _ in range(_MAX_STEPS):
            f = oz + t * dz - ground_height(gp, bumps, waves, t * du, v0 + t * dv, region)
            if f < _EPS_HIT:
                return t, region, 0.0, 0.0
            t += f / lip
            if t > b:
                break
        if t <= b and f < 0.05:  # a grazing ray that converges slowly: close enough
            return t, region, 0.0, 0.0
        if piece == n:
            break
        tb = b + 1e-7
        new_region = ground_region(gp, tb * du, v0 + tb * dv)
        if oz + b * dz < ground_height(gp, bumps, waves, tb * du, v0 + tb * dv, new_region):
            face = SIDEWALK if (region == SIDEWALK or new_region == SIDEWALK) else new_region
            if kind[piece] == 1:
                return b, face, 0.0, -1.0 if dv > 0.0 else 1.0
            return b, face, -1.0 if du > 0.0 else 1.0, 0.0
        a = b
        region = new_region
    return inf, 0, 0.0, 0.0


@nb.njit(cache=True)
def _ellipsoid_span(ox, oy, oz, dx, dy, dz, ea, eb, ec):
    """Entry and exit t of a ray with the origin-centred ellipsoid of semi-axes (ea, eb, ec); (inf, -inf) if none."""
    px, py, pz = ox / ea, oy / eb, oz / ec
    qx, qy, qz = dx / ea, dy / eb, dz / ec
    qa = qx * qx + qy * qy + qz * qz
    qb = px * qx + py * qy + pz * qz
    qc = px * px + py * py + pz * pz - 1.0
    disc = qb * qb - qa * qc
    if disc <= 0.0 or qa <= 0.0:
        return np.inf, -np.inf
    r = math.sqrt(disc)
    return (-qb - r) / qa, (-qb + r) / qa


@nb.njit(cache=True)
def _cylinder_span(ox, oy, dx, dy, radius):
    """Entry and exit t of a ray with the infinite cylinder x^2 + y^2 = radius^2; (inf, -inf) if none."""
    qa = dx * dx + dy * dy
    qb = ox * dx + oy * dy
    qc = ox * ox + oy * oy - radius * radius
    if qa < 1e-14:
        if qc <= 0.0:
            return -np.inf, np.inf
        return np.inf, -np.inf
    disc = qb * qb - qa * qc
    if disc <= 0.0:
        return np.inf, -np.inf
    r = math.sqrt(disc)
    return (-qb - r) / qa, (-qb + r) / qa


@nb.njit(cache=True)
def _hit_primitive(k, ox, oy, oz, dx, dy, dz, ptype, prot, pc, psize):
    """(t_in, t_out, nx, ny, nz) of the ray with primitive k, world normal at entry; t_in = inf for a miss."""
    inf = np.inf
    rx, ry, rz = ox - pc[k, 0], oy - pc[k, 1], oz - pc[k, 2]
    R = prot[k]
    lox = R[0, 0] * rx + R[0, 1] * ry + R[0, 2] * rz
    loy = R[1, 0] * rx + R[1, 1] * ry + R[1, 2] * rz
    loz = R[2, 0] * rx + R[2, 1] * ry + R[2, 2] * rz
    ldx = R[0, 0] * dx + R[0, 1] * dy + R[0, 2] * dz
    ldy = R[1, 0] * dx + R[1, 1] * dy + R[1, 2] * dz
    ldz = R[2, 0] * dx + R[2, 1] * dy + R[2, 2] * dz
    a, b, c = psize[k, 0], psize[k, 1], psize[k, 2]
    typ = ptype[k]
    nlx, nly, nlz = 0.0, 0.0, 0.0
    if typ == BOX:
        t_in, t_out = -inf, inf
        axis = -1
        lo = (lox, loy, loz)
        ld = (ldx, ldy, ldz)
        half = (a, b, c)
        for q in range(3):
            if abs(ld[q]) < 1e-14:
                if abs(lo[q]) > half[q]:
                    return inf, inf, 0.0, 0.0, 0.0
                continue
            ta = (-half[q] - lo[q]) / ld[q]
            tb = (half[q] - lo[q]) / ld[q]
            if ta > tb:
                ta, tb = tb, ta
            if ta > t_in:
                t_in = ta
                axis = q
            t_out = min(t_out, tb)
        if t_in > t_out or t_out <= 0.0 or axis < 0:
            return inf, inf, 0.0, 0.0, 0.0
        sign = -1.0 if ld[axis] > 0.0 else 1.0
        if axis == 0:
            nlx = sign
        elif axis == 1:
            nly = sign
        else:
            nlz = sign
        if psize[k, 3] > 0.0:
            ea, eb, ec = psize[k, 3] * a, psize[k, 4] * b, psize[k, 5] * c
            e_in, e_out = _ellipsoid_span(lox, loy, loz, ldx, ldy, ldz, ea, eb, ec)
            if e_in > t_in:
                t_in = e_in
                px, py, pz = lox + t_in * ldx, loy + t_in * ldy, loz + t_in * ldz
                nlx, nly, nlz = px / (ea * ea), py / (eb * eb), pz / (ec * ec)
            t_out = min(t_out, e_out)
            if t_in > t_out:
                return inf, inf, 0.0, 0.0, 0.0
    elif typ == ELLIPSOID:
        t_in, t_out = _ellipsoid_span(lox, loy, loz, ldx, ldy, ldz, a, b, c)
        if t_in > t_out:
            return inf, inf, 0.0, 0.0, 0.0
        px, py, pz = lox + t_in * ldx, loy + t_in * ldy, loz + t_in * ldz
        nlx, nly, nlz = px / (a * a), py / (b * b), pz / (c * c)
    else:
        c_in, c_out = _cylinder_span(lox, loy, ldx, ldy, a)
        if c_in > c_out:
            return inf, inf, 0.0, 0.0, 0.0
        if abs(ldz) < 1e-14:
            if abs(loz) > c:
                return inf, inf, 0.0, 0.0, 0.0
            z_in, z_out = -inf, inf
        else:
            z_in = (-c - loz) / ldz
            z_out = (c - loz) / ldz
            if z_in > z_out:
                z_in, z_out = z_out, z_in
        t_in = max(c_in, z_in)
        t_out = min(c_out, z_out)
        if t_in > t_out:
            return inf, inf, 0.0, 0.0, 0.0
        side = c_in >= z_in
        inner = psize[k, 3]
        if inner > 0.0:
            i_in, i_out = _cylinder_span(lox, loy, ldx, ldy, inner)
            if i_in < t_in < i_out:  # entered the hole through a cap: the material starts at the inner wall
                if i_out >= t_out:
                    return inf, inf, 0.0, 0.0, 0.0
                t_in = i_out
                px, py = lox + t_in * ldx, loy + t_in * ldy
                nlx, nly = -px / inner, -py / inner
                side = False
                nlz = 0.0
                inner = -1.0
        if inner >= 0.0:
            if side:
                nlx = (lox + t_in * ldx) / a
                nly = (loy + t_in * ldy) / a
            else:
                nlz = -1.0 if ldz > 0.0 else 1.0
    if t_in <= 0.0:
        return inf, inf, 0.0, 0.0, 0.0
    nx = R[0, 0] * nlx + R[1, 0] * nly + R[2, 0] * nlz
    ny = R[0, 1] * nlx + R[1, 1] * nly + R[2, 1] * nlz
    nz = R[0, 2] * nlx + R[1, 2] * nly + R[2, 2] * nlz
    norm = math.sqrt(nx * nx + ny * ny + nz * nz) + 1e-300
    return t_in, t_out, nx / norm, ny / norm, nz / norm


@nb.njit(cache=True)
def cast_rays(origins: np.ndarray, dirs: np.ndarray, t_max: float, gp: np.ndarray, bumps: np.ndarray,
              waves: np.ndarray, ptype: np.ndarray, prot: np.ndarray, pc: np.ndarray, psize: np.ndarray,
              obj_first: np.ndarray, obj_count: np.ndarray, obj_center: np.ndarray, obj_radius: np.ndarray,
              bin_start: np.ndarray, bin_items: np.ndarray) -> tuple[np.ndarray, ...]:
    """First hit of every ray: (t, t_exit, hit, normal, region).

    hit: primitive index, GROUND_HIT or NO_HIT; t = inf without a hit; t_exit: where the ray leaves the hit
    primitive (= t for ground); normal: unit, facing the ray; region: ROAD / SIDEWALK / TERRAIN for ground.
    """
    n = origins.shape[0]
    n_bins = bin_start.shape[0] - 1
    t_out = np.full(n, np.inf)
    t_exit = np.full(n, np.inf)
    hit = np.full(n, NO_HIT, dtype=np.int32)
    normal = np.zeros((n, 3))
    region = np.zeros(n, dtype=np.int8)
    c, s = gp[G_COS], gp[G_SIN]
    two_pi = 2.0 * math.pi
    for i in range(n):
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        az = math.atan2(dy, dx)
        if az < 0.0:
            az += two_pi
        b = min(int(az / two_pi * n_bins), n_bins - 1)
        best = t_max
        best_exit = t_max
        best_k = NO_HIT
        bnx, bny, bnz = 0.0, 0.0, 0.0
        for j in range(bin_start[b], bin_start[b + 1]):
            o = bin_items[j]
            ex = ox - obj_center[o, 0]
            ey = oy - obj_center[o, 1]
            ez = oz - obj_center[o, 2]
            rr = obj_radius[o]
            dist2 = ex * ex + ey * ey + ez * ez
            if math.sqrt(dist2) - rr - _ORDER_SLACK >= best:
                break  # bins are sorted by distance from a common eye: later objects are farther still
            qb = ex * dx + ey * dy + ez * dz
            disc = qb * qb - (dist2 - rr * rr)
            if disc < 0.0 or -qb + math.sqrt(disc) < 0.0:
                continue
            for k in range(obj_first[o], obj_first[o] + obj_count[o]):
                ti, to, nx, ny, nz = _hit_primitive(k, ox, oy, oz, dx, dy, dz, ptype, prot, pc, psize)
                if ti < best:
                    best, best_exit, best_k = ti, to, k
                    bnx, bny, bnz = nx, ny, nz
        du = c * dx + s * dy
        dv = -s * dx + c * dy
        v0 = -s * ox + c * oy + gp[G_VEGO]
        tg, reg, cnu, cnv = _trace_ground(gp, bumps, waves, oz, v0, dz, du, dv, best)
        if tg < best:
            best, best_exit, best_k = tg, tg, GROUND_HIT
            region[i] = reg
            if cnu != 0.0 or cnv != 0.0:
                bnx, bny, bnz = c * cnu - s * cnv, s * cnu + c * cnv, 0.0
            else:
                u = tg * du
                v = v0 + tg * dv
                h = 0.05
                hu = (ground_height(gp, bumps, waves, u + h, v, reg)
                      - ground_height(gp, bumps, waves, u - h, v, reg)) / (2 * h)
                hv = (ground_height(gp, bumps, waves, u, v + h, reg)
                      - ground_height(gp, bumps, waves, u, v - h, reg)) / (2 * h)
                nu, nv = -hu, -hv
                norm = math.sqrt(nu * nu + nv * nv + 1.0)
                bnx, bny, bnz = (c * nu - s * nv) / norm, (s * nu + c * nv) / norm, 1.0 / norm
        if best_k != NO_HIT:
            t_out[i] = best
            t_exit[i] = best_exit
            hit[i] = best_k
            if bnx * dx + bny * dy + bnz * dz > 0.0:
                bnx, bny, bnz = -bnx, -bny, -bnz
            normal[i, 0] = bnx
            normal[i, 1] = bny
            normal[i, 2] = bnz
    return t_out, t_exit, hit, normal, region


def azimuth_bins(obj_center: np.ndarray, obj_radius: np.ndarray, n_bins: int = 720,
                 eye_height: float = 0.17) -> tuple[np.ndarray, np.ndarray]:
    """CSR lists (bin_start, bin_items) of the objects whose bounding sphere reaches each azimuth sector.

    Items of a bin are sorted by the nearest distance of their sphere from the sensor (at `eye_height`).
    """
    n_obj = len(obj_radius)
    if n_obj == 0:
        return np.zeros(n_bins + 1, dtype=np.int64), np.zeros(0, dtype=np.int32)
    cx, cy = obj_center[:, 0], obj_center[:, 1]
    dxy = np.hypot(cx, cy)
    theta = np.arctan2(cy, cx)
    half = np.arcsin(np.clip(obj_radius / np.maximum(dxy, 1e-9), 0.0, 1.0))
    everywhere = dxy <= obj_radius * 1.0001
    width = 2.0 * np.pi / n_bins
    lo = np.floor((theta - half) / width).astype(np.int64)
    hi = np.floor((theta + half) / width).astype(np.int64)
    count = np.where(everywhere, n_bins, np.minimum(hi - lo + 1, n_bins))
    start = np.where(everywhere, 0, lo)
    obj = np.repeat(np.arange(n_obj), count)
    offset = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    bins = (np.repeat(start, count) + offset) % n_bins
    near = np.linalg.norm(obj_center - np.array([0.0, 0.0, eye_height]), axis=1) - obj_radius
    order = np.lexsort((near[obj], bins))
    bins, obj = bins[order], obj[order]
    bin_start = np.zeros(n_bins + 1, dtype=np.int64)
    np.cumsum(np.bincount(bins, minlength=n_bins), out=bin_start[1:])
    return bin_start, obj.astype(np.int32)
