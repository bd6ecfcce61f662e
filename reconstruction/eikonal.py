"""Surfaces from incident-angle maps: ``|∇z| = tan θ`` (an eikonal equation).

Under an orthographic camera the incident angle of a specular reflection is the zenith angle of
the normal, so an incident-angle map fixes the slope magnitude of the height field
``z(x, y)`` but not its direction. Two solvers:

* :func:`characteristic_strips` — Horn's characteristic strip expansion, the paper's Sec. 6.2:
  strips start on a small curve around the singular region (where ``θ ≈ 0`` and the normal
  faces the camera) and are integrated outwards along the characteristic equations of
  ``p² + q² = t(x, y)``, ``t = tan² θ``; each strip carries the height and the gradient.
* :func:`fast_marching_height` + :func:`refine_height` — the default: scikit-fmm's fast marching
  solves the eikonal as a whole from seeds where it is well posed (the occluding boundary), and
  a weighted least-squares refinement then lets pixels with a well-determined angle dominate
  while a thin-plate term carries the surface across the ill-conditioned near-normal region.

Pixel units throughout: ``x`` is the column, ``y`` points up (minus the row), ``z`` towards the
camera in pixels. Normals are ``(-p, -q, 1) / |…|`` with ``p = ∂z/∂x``, ``q = ∂z/∂y``.

References
----------
.. [1] B. K. P. Horn, "Obtaining shape from shading information", in *The Psychology of
   Computer Vision*, 1975 (characteristic strips).
.. [2] J. A. Sethian, "A fast marching level set method for monotonically advancing fronts",
   PNAS 93 (1996).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = [
    "gradient_to_normals",
    "height_gradient",
    "silhouette_seeds",
    "seed_level",
    "fast_marching_height",
    "refine_height",
    "characteristic_strips",
]

_MAX_SLOPE = np.tan(np.radians(89.0))


def gradient_to_normals(p, q):
    """Unit normals ``(-p, -q, 1)/|…|`` (camera frame) from height gradients."""
    n = np.stack([-p, -q, np.ones_like(p)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def height_gradient(z, mask):
    """``(p, q) = (∂z/∂x, ∂z/∂y)`` by central differences inside ``mask``, one-sided at its edge."""
    z = np.asarray(z, dtype=np.float64)
    m = np.asarray(mask, dtype=bool)

    def axis_diff(axis):
        fwd = np.zeros_like(z)
        bwd = np.zeros_like(z)
        has_f = np.zeros_like(m)
        has_b = np.zeros_like(m)
        sl = [slice(None)] * 2
        a, b = list(sl), list(sl)
        a[axis], b[axis] = slice(1, None), slice(None, -1)
        a, b = tuple(a), tuple(b)
        ok = m[a] & m[b]
        diff = z[a] - z[b]
        fwd[b] = np.where(ok, diff, 0.0)
        has_f[b] = ok
        bwd[a] = np.where(ok, diff, 0.0)
        has_b[a] = ok
        cnt = has_f.astype(float) + has_b
        return np.where(cnt > 0, (fwd + bwd) / np.maximum(cnt, 1), 0.0)

    p = axis_diff(1)
    q = -axis_diff(0)  # rows grow downwards, y upwards
    return p, q


def silhouette_seeds(theta_rad, mask, margin_deg=10.0, cap_deg=60.0):
    """Seed pixels on the silhouette where the surface turns away the most.

    A silhouette pixel is a seed when its angle is within ``margin_deg`` of the steepest
    silhouette angles (90th percentile) or above ``cap_deg``: occluding contours of domes
    (hemisphere rim, a cylinder's sides) and ground edges of uniformly tilted faces (a pyramid's
    base) qualify; cut edges across a gentle slope (a cylinder's ends) do not.
    """
    m = np.asarray(mask, dtype=bool)
    sil = m & ~ndimage.binary_erosion(m, border_value=0)
    th = np.degrees(np.nan_to_num(np.asarray(theta_rad, dtype=np.float64), nan=0.0))
    if not sil.any():
        return sil
    p90 = np.percentile(th[sil], 90)
    return sil & (th >= min(cap_deg, p90 - margin_deg))


def seed_level(theta_rad, mask, contour_deg=70.0, smooth_px=1.5):
    """Level-set function whose zero contour starts the fast march, and how it was chosen.

    Where the object has an occluding band (a dome: hemisphere, cylinder …), the start is the
    sub-pixel contour ``θ = contour_deg`` of the lightly smoothed angle map: a smooth front at
    a constant height of a dome, away from the occluding contour, where a pixel's height is
    ill-defined (the surface is vertical there). Otherwise (no such band, e.g. a pyramid whose
    faces all lean the same), the seeds are the silhouette pixels of :func:`silhouette_seeds`.

    Returns
    -------
    phi : (H, W) array, negative on the seed side.
    kind : ``"contour"`` or ``"silhouette"``.
    """
    m = np.asarray(mask, dtype=bool)
    th = np.degrees(np.nan_to_num(np.asarray(theta_rad, dtype=np.float64), nan=0.0))
    num = ndimage.gaussian_filter(np.where(m, th, 0.0), smooth_px)
    den = ndimage.gaussian_filter(m.astype(float), smooth_px)
    ths = np.where(m, num / np.maximum(den, 1e-9), 0.0)
    sil = m & ~ndimage.binary_erosion(m, border_value=0)
    steep = m & (ths >= contour_deg)
    # a dome: steep pixels form a thin band along (part of) the silhouette
    seeds = silhouette_seeds(theta_rad, m)
    if steep.sum() < 0.5 * m.sum() and (steep & sil).sum() >= 0.3 * sil.sum() and (m & ~steep).any():
        # the occluding silhouette itself is always on the outer side (at low resolution the
        # smoothed band can be thinner than a pixel)
        phi = np.where(m, contour_deg - ths, 1.0)
        phi = np.where(seeds & (th >= contour_deg), np.minimum(phi, -0.5), phi)
        return phi, "contour"
    return np.where(seeds, -0.5, 0.5), "silhouette"


def fast_marching_height(slope, mask, phi, order=1):
    """Height field solving ``|∇z| = slope``: zero on the zero contour of ``phi``, rising where
    ``phi > 0`` and falling where ``phi < 0`` (scikit-fmm, first order).

    Parameters
    ----------
    slope : (H, W) array
        ``tan θ`` per pixel (clipped to [1e-3, tan 89°]).
    mask : (H, W) bool
        Object pixels.
    phi : (H, W) array or bool
        Level-set function (see :func:`seed_level`), or a boolean seed image (seeds at 0).

    Returns
    -------
    (H, W) height in pixels, NaN outside ``mask`` and where the front does not reach.
    """
    import skfmm

    m = np.asarray(mask, dtype=bool)
    s = np.clip(np.nan_to_num(np.asarray(slope, dtype=np.float64), nan=1.0), 1e-3, _MAX_SLOPE)
    phi = np.asarray(phi)
    if phi.dtype == bool:
        phi = np.where(phi, -0.5, 0.5)
    phi = np.asarray(phi, dtype=np.float64)
    if not ((phi[m] < 0).any() and (phi[m] > 0).any()):
        raise ValueError("fast_marching_height: the level set has no zero contour inside the mask")
    t = skfmm.travel_time(np.ma.MaskedArray(phi, ~m), 1.0 / s, dx=1.0, order=order)
    z = np.ma.filled(t.astype(np.float64), np.nan)
    z = np.where(phi < 0, -z, z)
    z[~m] = np.nan
    return z


def _thin_plate(index, m):
    """Sparse second differences ``z_xx``, ``z_yy`` and ``sqrt(2) z_xy`` where they fit in the
    mask (the thin-plate energy; unlike the Laplacian it also penalises saddles)."""
    import scipy.sparse as sp

    n = int(m.sum())
    blocks = []

    def rows_for(offsets, weights, ok):
        r, c = np.nonzero(ok)
        k = np.arange(r.size)
        rows = np.concatenate([k] * len(offsets))
        cols = np.concatenate([index[r + dr, c + dc] for dr, dc in offsets])
        vals = np.concatenate([np.full(r.size, wt) for wt in weights])
        return sp.csr_matrix((vals, (rows, cols)), shape=(r.size, n))

    okx = np.zeros_like(m)
    okx[:, 1:-1] = m[:, 1:-1] & m[:, :-2] & m[:, 2:]
    blocks.append(rows_for([(0, -1), (0, 0), (0, 1)], [1.0, -2.0, 1.0], okx))
    oky = np.zeros_like(m)
    oky[1:-1, :] = m[1:-1, :] & m[:-2, :] & m[2:, :]
    blocks.append(rows_for([(-1, 0), (0, 0), (1, 0)], [1.0, -2.0, 1.0], oky))
    okxy = np.zeros_like(m)
    okxy[:-1, :-1] = m[:-1, :-1] & m[:-1, 1:] & m[1:, :-1] & m[1:, 1:]
    r2 = np.sqrt(2.0)
    blocks.append(rows_for([(0, 0), (0, 1), (1, 0), (1, 1)], [r2, -r2, -r2, r2], okxy))
    return sp.vstack(blocks).tocsr()


def _difference_operators(index, m):
    """Sparse central-difference operators ``(Gx, Gy)`` on the mask (one-sided at its edge),
    with ``x`` the column and ``y`` upwards."""
    import scipy.sparse as sp

    n = int(m.sum())
    r, c = np.nonzero(m)
    k = index[r, c]
    h, w = m.shape

    def build(dr, dc, sign):
        rp, cp = r + dr, c + dc
        rm, cm = r - dr, c - dc
        okp = (rp >= 0) & (rp < h) & (cp >= 0) & (cp < w)
        okp[okp] = m[rp[okp], cp[okp]]
        okm = (rm >= 0) & (rm < h) & (cm >= 0) & (cm < w)
        okm[okm] = m[rm[okm], cm[okm]]
        both = okp & okm
        rows, cols, vals = [], [], []
        # central where both neighbours exist, one-sided otherwise
        for sel, plus, minus, scale in ((both, True, True, 0.5), (okp & ~okm, True, False, 1.0),
                                        (okm & ~okp, False, True, 1.0)):
            kk = k[sel]
            if plus:
                rows.append(kk); cols.append(index[rp[sel], cp[sel]]); vals.append(np.full(kk.size, scale))
            else:
                rows.append(kk); cols.append(kk); vals.append(np.full(kk.size, scale))
            if minus:
                rows.append(kk); cols.append(index[rm[sel], cm[sel]]); vals.append(np.full(kk.size, -scale))
            else:
                rows.append(kk); cols.append(kk); vals.append(np.full(kk.size, -scale))
        G = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
        return sign * G

    gx = build(0, 1, 1.0)
    gy = build(1, 0, -1.0)  # one row down is y - 1
    return gx, gy


def _solve_spd(A, b):
    """Solve a sparse symmetric positive definite system: LU without pivoting on a symmetric
    fill-reducing ordering (as a Cholesky factorization would; faster than general pivoting)."""
    from scipy.sparse.linalg import splu

    lu = splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
              options={"SymmetricMode": True})
    return lu.solve(b)


def refine_height(z0, slope, weight, mask, smoothness=1.0, iterations=3, slope_cap=None, direction_weight=0.0,
                  anchors=None, anchor_weight=1.0):
    """Weighted Gauss-Newton refinement of a height field towards ``|∇z| = slope``.

    Minimises ``Σ_i w_i (|∇z|_i - s_i)² + smoothness Σ_i |∇²z|_i²`` over the mask, linearising
    ``|∇z|`` about the current surface (``|∇z| ≈ u·∇z`` with ``u`` the current uphill
    direction): the data fix only the slope *magnitude*, weighted by how well each pixel's
    angle is determined; the gradient *direction* and the near-normal pixels (small weight) are
    carried by the thin-plate term, which removes the direction artefacts of the fast march.

    Parameters
    ----------
    z0 : (H, W) initial height (e.g. :func:`fast_marching_height`), NaN outside the mask.
    slope : (H, W) measured ``tan θ``.
    weight : (H, W) inverse variance of ``slope`` (>= 0).
    mask : (H, W) bool.
    smoothness : float
        Weight of the thin-plate energy (squared second derivatives).
    iterations : int
        Gauss-Newton steps.
    slope_cap : float, optional
        Slopes above it are clipped (default tan 85°): finite differences cannot follow the
        surface at the occluding contour anyway.
    direction_weight : float
        Weight (relative to the data) of keeping the gradient's direction that of ``z0``:
        the slope magnitudes say nothing about it, and without this term the thin plate
        rounds the creases between flat faces (a pyramid turns into a cone).
    anchors : (H, W) bool, optional
        Pixels whose height stays that of ``z0`` (the fast march's start: an occluding
        contour or a ground edge at one height), weighted ``anchor_weight`` times the mean
        data weight: the boundary condition of the eikonal equation, without which a cone
        fits a pyramid's slopes as well as the pyramid.

    Returns
    -------
    (H, W) height, NaN outside the mask.
    """
    import scipy.sparse as sp

    m = np.asarray(mask, dtype=bool)
    cap = np.tan(np.radians(85.0)) if slope_cap is None else slope_cap
    n = int(m.sum())
    index = -np.ones(m.shape, dtype=np.int64)
    index[m] = np.arange(n)
    sv = np.clip(np.nan_to_num(slope, nan=0.0), 0.0, cap)[m]
    wv = np.clip(np.nan_to_num(weight, nan=0.0), 0.0, None)[m]
    z = np.nan_to_num(np.asarray(z0, dtype=np.float64), nan=0.0)[m]
    Gx, Gy = _difference_operators(index, m)
    L = _thin_plate(index, m)
    LtL = smoothness * (L.T @ L) + 1e-9 * sp.identity(n)
    if direction_weight > 0:
        p0, q0 = Gx @ z, Gy @ z
        g0 = np.hypot(p0, q0)
        ok0 = g0 > 1e-9
        vx = np.where(ok0, -q0 / np.where(ok0, g0, 1.0), 0.0)
        vy = np.where(ok0, p0 / np.where(ok0, g0, 1.0), 0.0)
        Jp = sp.diags(vx) @ Gx + sp.diags(vy) @ Gy
        LtL = LtL + Jp.T @ sp.diags(direction_weight * wv) @ Jp
    wa = np.zeros(n)
    za = z.copy()
    if anchors is not None:
        wa = np.where(np.asarray(anchors, dtype=bool)[m], anchor_weight * max(float(np.mean(wv)), 1e-300), 0.0)
    for _ in range(iterations):
        p, q = Gx @ z, Gy @ z
        g = np.hypot(p, q)
        ok = g > 1e-9
        ux = np.where(ok, p / np.where(ok, g, 1.0), 0.0)
        uy = np.where(ok, q / np.where(ok, g, 1.0), 0.0)
        J = sp.diags(ux) @ Gx + sp.diags(uy) @ Gy
        A = J.T @ sp.diags(wv) @ J + LtL + sp.diags(wa)
        z = _solve_spd(A, J.T @ (wv * sv) + wa * za)
        if not wa.any():
            z -= z.max()
    out = np.full(m.shape, np.nan)
    out[m] = z
    return out


def characteristic_strips(theta_rad, mask, step_px=0.5, start_deg=None, n_start=None):
    """Horn's characteristic strip expansion of ``p² + q² = t(x, y)``, ``t = tan² θ`` (Sec. 6.2).

    Strips start on the boundary of the singular region (``θ`` below ``start_deg``, default the
    5th percentile of ``θ`` plus 5°, the pixels that face the camera), with the gradient normal
    to that boundary and pointing into it (the surface rises towards the camera-facing point),
    and run outwards with the characteristic equations (arc length ``τ`` scaled so each step
    advances ``step_px`` in the image)::

        dx/dτ = -p,  dy/dτ = -q,  dz/dτ = -(p² + q²),  dp/dτ = -t_x / 2,  dq/dτ = -t_y / 2

    A strip stops where it leaves the mask or meets an unknown angle. Pixels crossed by strips
    get the mean gradient of the strips; inside the start region the gradient points to the
    region's centre with magnitude ``tan θ``; other pixels take the nearest strip's gradient.

    Parameters
    ----------
    theta_rad : (H, W) incident angle per pixel (NaN where unknown).
    mask : (H, W) bool.

    Returns
    -------
    normals : (H, W, 3) unit normals (zeros where not reached).
    reached : (H, W) bool, pixels with a gradient.
    height : (H, W) height in pixels along the strips (NaN where no strip passed).
    """
    m = np.asarray(mask, dtype=bool)
    th = np.asarray(theta_rad, dtype=np.float64)
    known = m & np.isfinite(th)
    h, w = m.shape
    t = np.where(known, np.tan(np.clip(np.nan_to_num(th), 0, np.radians(89.0))) ** 2, np.nan)
    # gradient of t, by central differences over known pixels (t smoothed lightly, as the paper
    # samples contour lines of the intensity)
    tf = ndimage.gaussian_filter(np.nan_to_num(t), 1.0)
    wf = ndimage.gaussian_filter(known.astype(float), 1.0)
    ts = np.where(known, tf / np.maximum(wf, 1e-9), 0.0)
    # derivatives in the (x right, y up) frame
    t_x = np.gradient(ts, axis=1)
    t_y = -np.gradient(ts, axis=0)

    if start_deg is None:
        start_deg = np.degrees(np.percentile(th[known], 5)) + 5.0 if known.any() else 5.0
    region = known & (th <= np.radians(start_deg))
    if not region.any():
        return np.zeros((h, w, 3)), np.zeros((h, w), bool), np.full((h, w), np.nan)
    # inward gradient on the boundary of the start region: minus the gradient of the distance
    # to the region's outside (points into the region)
    dist = ndimage.distance_transform_edt(region)
    g_r, g_c = np.gradient(ndimage.gaussian_filter(dist, 1.0))
    edge = region & ~ndimage.binary_erosion(region)
    er, ec = np.nonzero(edge)
    # uphill direction in (x, y): towards growing distance, i.e. (g_c, -g_r)
    ux, uy = g_c[er, ec], -g_r[er, ec]
    norm = np.hypot(ux, uy)
    ok = norm > 1e-9
    er, ec, ux, uy = er[ok], ec[ok], ux[ok] / norm[ok], uy[ok] / norm[ok]
    s0 = np.sqrt(t[er, ec])
    x = ec.astype(float)
    y = -er.astype(float)
    p = s0 * ux
    q = s0 * uy
    z = np.zeros_like(x)

    sum_p = np.zeros((h, w))
    sum_q = np.zeros((h, w))
    sum_z = np.zeros((h, w))
    cnt = np.zeros((h, w))
    alive = np.ones(x.size, dtype=bool)
    max_steps = int(4 * (h + w) / step_px)
    for _ in range(max_steps):
        if not alive.any():
            break
        g = np.hypot(p, q)
        dtau = step_px / np.maximum(g, 1e-6)
        coords = np.stack([-y, x])  # (row, column)
        tx = ndimage.map_coordinates(t_x, coords, order=1, mode="nearest")
        ty = ndimage.map_coordinates(t_y, coords, order=1, mode="nearest")
        # outward step (τ decreasing along the uphill characteristic)
        x_n = x - p * dtau
        y_n = y - q * dtau
        z_n = z - (p * p + q * q) * dtau
        p_n = p - 0.5 * tx * dtau
        q_n = q - 0.5 * ty * dtau
        r_i = np.rint(-y_n).astype(np.int64)
        c_i = np.rint(x_n).astype(np.int64)
        inside = (r_i >= 0) & (r_i < h) & (c_i >= 0) & (c_i < w)
        r_c, c_c = np.clip(r_i, 0, h - 1), np.clip(c_i, 0, w - 1)
        inside &= known[r_c, c_c]
        alive &= inside & (g > 1e-9)
        # keep the strip on its constraint p² + q² = t (the paper's contour intersection)
        t_here = t[r_c, c_c]
        gn = np.hypot(p_n, q_n)
        scale = np.where(gn > 0, np.sqrt(np.nan_to_num(t_here)) / np.maximum(gn, 1e-12), 1.0)
        p_n, q_n = p_n * scale, q_n * scale
        x, y, z, p, q = (np.where(alive, a, b) for a, b in
                         ((x_n, x), (y_n, y), (z_n, z), (p_n, p), (q_n, q)))
        ra, ca = r_c[alive], c_c[alive]
        np.add.at(sum_p, (ra, ca), p[alive])
        np.add.at(sum_q, (ra, ca), q[alive])
        np.add.at(sum_z, (ra, ca), z[alive])
        np.add.at(cnt, (ra, ca), 1.0)

    hit = cnt > 0
    P = np.where(hit, sum_p / np.maximum(cnt, 1), 0.0)
    Q = np.where(hit, sum_q / np.maximum(cnt, 1), 0.0)
    Z = np.where(hit, sum_z / np.maximum(cnt, 1), np.nan)
    # start region: gradient towards the region's centre (uphill), magnitude tan θ
    rr, rc = np.nonzero(region)
    s_in = np.sqrt(t[rr, rc])
    ux, uy = g_c[rr, rc], -g_r[rr, rc]
    nrm = np.hypot(ux, uy)
    ux = np.where(nrm > 1e-9, ux / np.maximum(nrm, 1e-12), 0.0)
    uy = np.where(nrm > 1e-9, uy / np.maximum(nrm, 1e-12), 0.0)
    P[rr, rc], Q[rr, rc] = s_in * ux, s_in * uy
    Z[rr, rc] = 0.0
    hit |= region
    # pixels between strips: nearest strip sample
    fill = known & ~hit
    if fill.any() and hit.any():
        dist_px, (ir, ic) = ndimage.distance_transform_edt(~hit, return_indices=True)
        fill &= dist_px <= 3.0
        P[fill], Q[fill] = P[ir[fill], ic[fill]], Q[ir[fill], ic[fill]]
        hit |= fill
    normals = np.where(hit[..., None], gradient_to_normals(P, Q), 0.0)
    return normals, hit & m, np.where(hit & m, Z, np.nan)
