"""The 180° ambiguity of the azimuth, resolved for the whole object at once.

Polarization gives each pixel the axis of its normal's image-plane part, ``±o`` with
``o = sin θ (cos φ, sin φ)`` (φ known modulo 180°). The signs ``s_i = ±1`` are chosen to
minimise one energy over the object (an Ising model, ``E(s) = -Σ J_ij s_i s_j - Σ h_i s_i``):

* **smoothness** of the normal field, to first order between neighbours,
  ``|s_i o_i - s_j o_j|²``, and to second order along lines of three pixels,
  ``|s_i o_i - 2 s_j o_j + s_k o_k|²``. The second-order term is what tells a ridge or a
  valley (where the normal's image-plane part passes through zero and turns round, like
  the top of a cylinder or of a torus's tube) from a fold (the same axis on both sides with
  the same sign, a kink in the surface's curvature): first-order smoothness alone cannot,
  since ``o`` is near zero there;
* **occluding contours**, the one cue to the global sign (a surface seen under an
  orthographic camera and its mirror image ``z → -z`` give the same polarization): at an
  occluding contour the surface turns away from the camera, so its normal points out of
  the object region. Contours are the silhouette (outer edges and the edges of holes) where
  the surface is steep, and, inside the object, steep pixels (a tilted torus's tube hiding
  part of its hole), where the normal points the way the zenith grows. Where an object has
  no occluding contour (a wavy open sheet) its silhouette pixels vote with a weight that
  vanishes at normal incidence: the convex choice, edges lower than the middle; the data
  cannot tell (the mirror sheet gives the same images).

The energy is minimised in three stages:

1. regions of confidently and consistently oriented pixels (joined by strong first-order
   agreement, their relative orientation fixed along a maximum spanning forest) are
   oriented jointly: by the energy within and between them, plus, for every connected group
   of the other (free) pixels, the group's energy once completed for each sign choice of
   the regions it touches (where it touches more than six, pairwise couplings between
   neighbouring regions through their nearest free pixels); exactly, by enumeration, for up
   to :data:`EXACT_REGIONS` regions, otherwise by the best of many seeded descents;
2. the free pixels (near normal incidence, ridges, isolated) by iterated conditional modes,
   ring by ring outwards from the regions;
3. whole cells (a region, or the free pixels of a 4 px square nearest one region) are
   flipped where the exact energy falls: over the cells it is again an Ising model,
   minimised as in 1, then the free pixels are swept again.

Every input is data (no ground truth), so this works on real captures.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["EXACT_REGIONS", "coupling_matrix", "crease_strength", "contour_anchors", "resolve_signs", "resolve_azimuth_global"]

#: regions oriented jointly by enumerating every choice of their signs
EXACT_REGIONS = 14

# line neighbours (row, column offsets) of the first- and second-order terms
_DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))


def _pairs(mask, dr, dc, step=1):
    """Flat indices (i, j) of mask pixels and their neighbour ``step`` times (dr, dc) away."""
    H, W = mask.shape
    r, c = np.nonzero(mask)
    r2, c2 = r + step * dr, c + step * dc
    ok = (r2 >= 0) & (r2 < H) & (c2 >= 0) & (c2 < W)
    r, c, r2, c2 = r[ok], c[ok], r2[ok], c2[ok]
    ok = mask[r2, c2]
    return r[ok] * W + c[ok], r2[ok] * W + c2[ok]


def coupling_matrix(o, confidence, mask, first=1.0, second=1.0, scales=(1, 2, 4), bridge=8):
    """The couplings ``J`` (sparse, symmetric, over flat pixel indices) of the smoothness energy.

    Parameters
    ----------
    o : (H, W, 2) one representative of each pixel's image-plane normal (sign arbitrary).
    confidence : (H, W) weight of each pixel (0 to 1).
    mask : (H, W) bool.
    first, second : weights of the first- and second-order terms.
    scales : spacings (pixels) of the second-order triples.
    bridge : a wider spacing whose triples count only where their middle pixel is not
        confident (0: none).
    """
    import scipy.sparse as sp

    H, W = mask.shape
    of = o.reshape(-1, 2)
    raw = np.clip(confidence, 0.0, 1.0).ravel()
    cf = (confidence * (1.0 - crease_strength(o, mask)) ** 2).ravel()
    rows, cols, vals = [], [], []

    def add(i, j, v):
        rows.extend([i, j])
        cols.extend([j, i])
        vals.extend([v, v])

    for dr, dc in _DIRECTIONS:
        scale = 1.0 if dr == 0 or dc == 0 else 0.5          # diagonals: longer steps
        i, j = _pairs(mask, dr, dc)
        w = first * scale * np.sqrt(cf[i] * cf[j])
        add(i, j, 2.0 * w * np.einsum("ij,ij->i", of[i], of[j]))
        # triples i - j - k along the line (j the middle), at several spacings: across a
        # ridge the normals near it are too small to tell, those a few pixels away are not.
        # The widest (``bridge``) only where the middle itself says nothing (its confidence,
        # not a crease's cut): on a low, long wave the band without polarization can be wider
        # than 8 px, while across a short wave's confident slopes or a crease so long a triple
        # is not a line
        for step in tuple(scales) + ((bridge,) if bridge else ()):
            i, k = _pairs(mask, dr, dc, 2 * step)
            j = i + step * (dr * W + dc)
            ok = mask.ravel()[j]
            i, j, k = i[ok], j[ok], k[ok]
            w = second * scale * np.sqrt(cf[i] * cf[k])
            if step == bridge:
                # and only along a path inside the mask (not across a hole or a gap)
                inside = np.ones(i.size, dtype=bool)
                for t in range(1, 2 * step):
                    inside &= mask.ravel()[i + t * (dr * W + dc)]
                w = w * (1.0 - raw[j]) * inside
            add(i, j, 4.0 * w * np.einsum("ij,ij->i", of[i], of[j]))
            add(j, k, 4.0 * w * np.einsum("ij,ij->i", of[j], of[k]))
            add(i, k, -2.0 * w * np.einsum("ij,ij->i", of[i], of[k]))
    n = H * W
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


def crease_strength(o, mask, scale=0.1):
    """Per pixel, 0 to 1: how sharply the axis turns towards a neighbour (an edge between
    flat faces, or an occlusion), ``(1 - |cos|)`` of the angle between the axes times their
    smaller magnitude over ``scale`` (near-normal pixels, whose axes are noise, count
    little). Smoothness couplings are not trusted across such pixels."""
    H, W = mask.shape
    nrm = np.linalg.norm(o, axis=-1)
    a = np.where(nrm[..., None] > 1e-12, o / np.maximum(nrm, 1e-12)[..., None], 0.0)
    out = np.zeros((H, W))
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r0, r1 = max(0, -dr), H - max(0, dr)
        c0, c1 = max(0, -dc), W - max(0, dc)
        A = a[r0:r1, c0:c1]
        B = a[r0 + dr:r1 + dr, c0 + dc:c1 + dc]
        m = mask[r0:r1, c0:c1] & mask[r0 + dr:r1 + dr, c0 + dc:c1 + dc]
        turn = (1.0 - np.abs(np.sum(A * B, axis=-1))) * np.minimum(nrm[r0:r1, c0:c1], nrm[r0 + dr:r1 + dr, c0 + dc:c1 + dc])
        v = np.where(m, np.clip(turn / scale, 0.0, 1.0), 0.0)
        out[r0:r1, c0:c1] = np.maximum(out[r0:r1, c0:c1], v)
        out[r0 + dr:r1 + dr, c0 + dc:c1 + dc] = np.maximum(out[r0 + dr:r1 + dr, c0 + dc:c1 + dc], v)
    return out


def _outward(mask, smooth_px=1.5):
    """Unit vectors (H, W, 2) (x right, y up) pointing out of ``mask`` at its edge."""
    dist = ndimage.gaussian_filter(ndimage.distance_transform_edt(mask), smooth_px)
    gy, gx = np.gradient(dist)
    out = np.stack([-gx, gy], axis=-1)
    norm = np.linalg.norm(out, axis=-1, keepdims=True)
    return np.where(norm > 1e-12, out / np.maximum(norm, 1e-12), 0.0)


def contour_anchors(o, theta, confidence, mask, steep_deg=70.0, hole_deg=45.0, band_px=2.0, cut_deg=45.0,
                    cut_weight=0.01, centre_weight=3.0, centre_fraction=0.5, return_evidence=False):
    """Unary terms ``h`` (H, W): evidence for the sign of each pixel's representative ``o``
    from occluding contours (positive: ``o`` itself points the right way).

    * silhouette pixels (within ``band_px`` of the outer edge) vote for the outward
      direction with weight ``sin² θ`` times the alignment of ``o`` with it;
    * pixels at the edge of a hole in the mask vote the same way where ``θ >= hole_deg``
      (a hole of dark, near-normal pixels, such as the camera's hole in the lighting
      dome, has no occluding edge);
    * steep pixels inside the object (``θ >= steep_deg``) vote for the direction in which
      the (smoothed) zenith grows;
    * every pixel near the middle of its connected part (Gaussian weight, ``centre_fraction``
      of the part's RMS radius) votes, weakly, for pointing away from the part's centre.

    The votes of edges that are not occluding (a sheet's, a shallow cap's rim) and of the
    middle are priors, weighted ``cut_weight`` (1 % of an occluding contour's): they decide
    what the smoothness leaves open (the global sign of a part with no occluding contour,
    parts no coupling joins), never a low wave's ridge against it, which they did at 10 %.

    With ``return_evidence``, also the weight (H, W) of the occluding-contour evidence alone
    (the first three kinds of vote, without the alignment): where a part has none, its sign
    is the convex prior's choice, which the data cannot confirm.
    """
    m = np.asarray(mask, dtype=bool)
    th = np.where(m, np.nan_to_num(theta), 0.0)
    s2 = np.sin(th) ** 2
    nrm = np.linalg.norm(o, axis=-1)
    a = np.where(nrm[..., None] > 1e-12, o / np.maximum(nrm, 1e-12)[..., None], 0.0)
    h = np.zeros(m.shape)
    filled = ndimage.binary_fill_holes(m)
    holes = filled & ~m
    dist_out = ndimage.distance_transform_edt(filled)
    out = _outward(m)
    align = np.sum(a * out, axis=-1)
    outer = m & (dist_out <= band_px)
    near_hole = m & ndimage.binary_dilation(holes, iterations=int(np.ceil(band_px))) & ~outer
    use_hole = near_hole & (th >= np.radians(hole_deg))
    edge = outer | use_hole
    # an occluding contour (steep) is strong evidence; a cut edge (a sheet's, a cylinder's
    # end, a shallow cap's rim) only a prior, which decides nothing the smoothness can
    occluding = np.clip((th - np.radians(cut_deg)) / np.radians(steep_deg - cut_deg), 0.0, 1.0)
    h[edge] = (s2 * align * (cut_weight + (1.0 - cut_weight) * occluding))[edge]
    # steep interior pixels: the surface rolls away towards growing zenith
    num = ndimage.gaussian_filter(np.where(m, th, 0.0), 1.0)
    den = ndimage.gaussian_filter(m.astype(float), 1.0)
    ths = np.where(m, num / np.maximum(den, 1e-9), 0.0)
    gy, gx = np.gradient(ths)
    grad = np.stack([gx, -gy], axis=-1)
    gn = np.linalg.norm(grad, axis=-1)
    inner = m & ~edge & (th >= np.radians(steep_deg)) & (gn > 1e-6)
    cosg = np.sum(a * grad, axis=-1) / np.maximum(gn, 1e-12)
    h[inner] = (s2 * cosg)[inner]
    evidence = np.zeros(m.shape)
    evidence[edge] = (s2 * occluding)[edge]
    evidence[inner] = s2[inner]
    # and, weaker still, the middle of each part bulges towards the camera: its normals point
    # away from the part's centre (what decides a wavy sheet, which has no occluding contour
    # and whose edges may cut its waves anywhere)
    labels, count = ndimage.label(m)
    if count:
        r, c = np.nonzero(m)
        lab = labels[r, c] - 1
        cnt = np.bincount(lab, minlength=count)
        cr, cc = np.bincount(lab, r, count) / cnt, np.bincount(lab, c, count) / cnt
        dx, dy = c - cc[lab], -(r - cr[lab])
        rad = np.sqrt(np.bincount(lab, dx * dx + dy * dy, count) / cnt)[lab]
        dist = np.hypot(dx, dy)
        w = np.exp(-0.5 * (dist / np.maximum(centre_fraction * rad, 1.0)) ** 2)
        radial = (a[r, c, 0] * dx + a[r, c, 1] * dy) / np.maximum(dist, 1e-9)
        h[r, c] += centre_weight * cut_weight * s2[r, c] * radial * w
    c = np.clip(confidence, 0.0, None)
    return (h * c, evidence * c) if return_evidence else h * c


def _regions(o, confidence, mask, min_confidence=0.2, min_agreement=0.8, smooth_agreement=0.9,
             smooth_magnitude=0.2, ridge_px=3.0):
    """Regions of pixels joined by strong first-order agreement (neighbours whose axes agree
    within ``acos(min_agreement)``), each pixel's orientation fixed relative to its region
    along a maximum spanning forest of the agreement strengths. Returns the region label of
    each flat pixel (-1: none) and its orientation (±1)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree

    H, W = mask.shape
    n = H * W
    of = o.reshape(-1, 2)
    cf = confidence.ravel()
    nrm = np.linalg.norm(of, axis=1)
    strong = mask.ravel() & (cf >= min_confidence) & (nrm > 1e-9)
    # only pixels inside smooth patches: every 4-neighbour confident, with an axis and a
    # magnitude close to the pixel's own (no crease, ridge, fold or occlusion next to it)
    smooth = strong.copy()
    for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        r, c = np.divmod(np.arange(n), W)
        r2, c2 = r + dr, c + dc
        inside = (r2 >= 0) & (r2 < H) & (c2 >= 0) & (c2 < W)
        j = np.where(inside, r2 * W + c2, 0)
        ok = inside & strong[j]
        cosang = np.abs(np.einsum("ij,ij->i", of, of[j])) / np.maximum(nrm * nrm[j], 1e-300)
        ok &= (cosang >= smooth_agreement) & (np.abs(nrm - nrm[j]) <= smooth_magnitude)
        smooth &= ok
    # and far from any zero of the field (a ridge, a valley, a peak): the magnitude |o|
    # at least ``ridge_px`` times its change per pixel
    mag = np.where(mask, nrm.reshape(H, W), 0.0)
    gy, gx = np.gradient(mag)
    change = np.hypot(gx, gy).ravel()
    smooth &= nrm >= ridge_px * change
    strong = smooth
    ii, jj, ww = [], [], []
    for dr, dc in _DIRECTIONS[:2]:
        i, j = _pairs(mask, dr, dc)
        ok = strong[i] & strong[j]
        i, j = i[ok], j[ok]
        cosang = np.einsum("ij,ij->i", of[i], of[j]) / (nrm[i] * nrm[j])
        ok = np.abs(cosang) >= min_agreement
        ii.append(i[ok])
        jj.append(j[ok])
        ww.append((np.abs(cosang) * np.sqrt(cf[i] * cf[j]))[ok])
    i, j, w = np.concatenate(ii), np.concatenate(jj), np.concatenate(ww)
    label = np.full(n, -1, dtype=np.int64)
    orient = np.ones(n)
    if i.size == 0:
        return label, orient
    # maximum spanning forest: minimum spanning forest of (2 - strength) > 0
    G = sp.csr_matrix((2.0 - w, (i, j)), shape=(n, n))
    T = minimum_spanning_tree(G)
    T = T + T.T
    count, comp = connected_components(T, directed=False)
    nodes = np.nonzero(strong)[0]
    # one breadth-first pass from a virtual root joined to one pixel of every component
    roots = nodes[np.unique(comp[nodes], return_index=True)[1]]
    Tc = T.tocoo()
    A = sp.csr_matrix((np.ones(Tc.nnz + roots.size),
                       (np.concatenate([Tc.row, np.full(roots.size, n)]), np.concatenate([Tc.col, roots]))),
                      shape=(n + 1, n + 1))
    order, pred = breadth_first_order(A, n, directed=False, return_predecessors=True)
    # relation along every tree edge: the sign of the two representatives' dot product;
    # orientation relative to the component's root by pointer jumping
    ptr = np.where(pred < 0, n, pred)
    ptr[n] = n
    ofx = np.concatenate([of, np.zeros((1, 2))])
    sign = np.where(np.einsum("ij,ij->i", ofx, ofx[ptr]) >= 0, 1.0, -1.0)
    sign[ptr == n] = 1.0
    sign[n] = 1.0
    while np.any(ptr != n):
        sign = sign * sign[ptr]
        ptr = ptr[ptr]
    _, lab = np.unique(comp[nodes], return_inverse=True)
    label[nodes] = lab
    orient[nodes] = sign[nodes]
    return label, orient


def _icm_classes(Jc, free_idx, colour):
    """The colour classes of ``free_idx`` with their rows of the couplings."""
    out = []
    for col in range(9):
        sel = free_idx[colour[free_idx] == col]
        if sel.size:
            out.append((sel, Jc[sel]))
    return out


def _icm(classes, h, s, sweeps):
    """Iterated conditional modes over prepared colour classes (:func:`_icm_classes`); pixels
    of one class share no coupling, so each class is updated at once."""
    for _ in range(sweeps):
        changed = 0
        for sel, rows in classes:
            field = rows @ s + h[sel]
            new = np.where(field > 0, 1.0, np.where(field < 0, -1.0, s[sel]))
            new = np.where(new == 0, 1.0, new)
            changed += int(np.sum(new != s[sel]))
            s[sel] = new
        if changed == 0:
            break
    return s


def _complete(rings, h, s, sweeps):
    """Iterated conditional modes over free pixels prepared by :func:`_rings`: ring by ring
    outwards from the fixed pixels (each ring by the field of the pixels set before it), then
    ``sweeps`` sweeps over all of them. ``s`` is changed in place and returned."""
    steps, classes = rings
    for ring, ring_classes in steps:
        s = _icm(ring_classes, h, s, 1)
        s[ring] = np.where(s[ring] == 0, 1.0, s[ring])
    return _icm(classes, h, s, sweeps)


def _rings(Jc, free_idx, dist, colour):
    """The rings of ``free_idx`` by distance ``dist`` from the fixed pixels, and the colour
    classes of all of them (the work of :func:`_complete` that no sign changes)."""
    steps = [(ring, _icm_classes(Jc, ring, colour))
             for ring in (free_idx[dist[free_idx] == level] for level in np.unique(dist[free_idx]))]
    return steps, _icm_classes(Jc, free_idx, colour)


def _gap_tables(Jc, h, region_of, orient, free, colour, dist, max_regions=6, sweeps=8):
    """The energy of every connected group of free pixels as a function of the signs of the
    regions it touches: for each of their ``2^r`` sign choices, the group is completed as in
    the final pass (:func:`_complete`) and the energy of the terms that involve it is kept.

    Returns a list of ``(regions, energies)``, ``energies[b]`` for the choice whose bit ``i``
    set means region ``regions[i]`` flipped (sign -1), and the groups (flat pixel indices)
    that touch more than ``max_regions`` regions, for :func:`_gap_couplings`.
    """
    tables, many = [], []
    labels, count = ndimage.label(free, structure=np.ones((3, 3)))
    lab = labels.ravel()
    n = Jc.shape[0]
    for g in range(1, count + 1):
        G = np.nonzero(lab == g)[0]
        JG = Jc[G]
        touched = np.unique(JG.indices)
        regs = np.unique(region_of[touched])
        regs = regs[regs >= 0]
        if regs.size == 0:
            continue
        if regs.size > max_regions:
            many.append(G)
            continue
        fixed = touched[region_of[touched] >= 0]
        which = np.searchsorted(regs, region_of[fixed])
        rings = _rings(Jc, G, dist, colour)
        JGG = JG[:, G]
        energies = np.empty(2 ** regs.size)
        for b in range(energies.size):
            sig = np.where((b >> np.arange(regs.size)) & 1, -1.0, 1.0)
            s = np.zeros(n)
            s[fixed] = orient[fixed] * sig[which]
            s = _complete(rings, h, s, sweeps)
            sG = s[G]
            sF = s.copy()
            sF[G] = 0.0
            energies[b] = -0.5 * sG @ (JGG @ sG) - sG @ (JG @ sF) - h[G] @ sG
        tables.append((regs, energies))
    return tables, many


def _gap_couplings(Jc, h, region_of, orient, groups, nearest, colour, sweeps=8):
    """Pairwise approximation of the energy of groups of free pixels that touch many regions.

    Each free pixel belongs to its nearest region's part of the group. For every pair of
    regions whose parts are coupled, their two parts are solved (iterated conditional modes)
    for each of the four sign choices of the two regions, the rest left unset; the energies
    ``E(σa, σb)`` decompose as ``c - J σa σb - ha σa - hb σb``. A region's unary parts are
    shared among its pairs. Only neighbouring parts are solved, so the work grows with the
    group's size, not with the square of the regions it touches.

    Returns ``({(a, b): J}, {a: h})``.
    """
    pair_j, unary = {}, {}
    n = Jc.shape[0]
    for G in groups:
        JG = Jc[G].tocoo()
        i, j = G[JG.row], JG.col
        ci, cj = nearest[i], nearest[j]
        ok = (ci != cj) & (ci >= 0) & (cj >= 0)
        if not ok.any():
            continue
        pairs = np.unique(np.sort(np.stack([ci[ok], cj[ok]], 1), axis=1), axis=0)
        degree = np.bincount(pairs.ravel(), minlength=int(pairs.max()) + 1)
        part = nearest[G]
        for ka, kb in pairs:
            sub = G[(part == ka) | (part == kb)]
            Js = Jc[sub]
            touched = np.unique(Js.indices)
            fixed = touched[(region_of[touched] == ka) | (region_of[touched] == kb)]
            classes = _icm_classes(Jc, sub, colour)
            Jss = Js[:, sub]
            E = {}
            for sa in (1.0, -1.0):
                for sb in (1.0, -1.0):
                    s = np.zeros(n)
                    s[fixed] = orient[fixed] * np.where(region_of[fixed] == ka, sa, sb)
                    s = _icm(classes, h, s, sweeps)
                    sS = s[sub]
                    sF = s.copy()
                    sF[sub] = 0.0
                    E[sa, sb] = -0.5 * sS @ (Jss @ sS) - sS @ (Js @ sF) - h[sub] @ sS
            pair_j[(ka, kb)] = pair_j.get((ka, kb), 0.0) + 0.25 * (
                E[1.0, -1.0] + E[-1.0, 1.0] - E[1.0, 1.0] - E[-1.0, -1.0])
            ha = 0.25 * (E[-1.0, 1.0] + E[-1.0, -1.0] - E[1.0, 1.0] - E[1.0, -1.0])
            hb = 0.25 * (E[1.0, -1.0] + E[-1.0, -1.0] - E[1.0, 1.0] - E[-1.0, 1.0])
            unary[ka] = unary.get(ka, 0.0) + ha / degree[ka]
            unary[kb] = unary.get(kb, 0.0) + hb / degree[kb]
    return pair_j, unary


def _table_energy(configs, tables):
    """Energies (C,) of the groups' tables for region sign choices ``configs`` (C, B)."""
    e = np.zeros(configs.shape[0])
    for regs, energies in tables:
        bits = (configs[:, regs] < 0).astype(np.int64)
        e += energies[bits @ (1 << np.arange(regs.size))]
    return e


def _minimise_regions(Jr, hr, tables, starts=256, passes=50):
    """Region signs (B,) minimising ``-σᵀJrσ/2 - hrᵀσ`` plus the groups' tables
    (:func:`_table_energy`): exactly by enumeration for up to :data:`EXACT_REGIONS` regions,
    otherwise the best of ``starts`` descents by single flips (from all +1, the unary terms'
    choice and random starts from a fixed seed, so the result is reproducible and never
    worse than all +1), run side by side."""
    import itertools

    B = hr.size

    def energy(configs):
        return -0.5 * np.einsum("ci,ij,cj->c", configs, Jr, configs) - configs @ hr + _table_energy(configs, tables)

    if B <= EXACT_REGIONS:
        configs = np.array(list(itertools.product((1.0, -1.0), repeat=B)))
        return configs[int(np.argmin(energy(configs)))]
    # fewer starts for many regions: the work of a pass grows as starts x B²
    starts = int(np.clip(4_000_000 // (B * B), 16, starts))
    C = np.random.default_rng(0).choice([-1.0, 1.0], size=(starts, B))
    C[0] = 1.0
    C[1] = np.where(hr >= 0, 1.0, -1.0)
    touching = [[(regs, energies, int(np.searchsorted(regs, k))) for regs, energies in tables if k in regs]
                for k in range(B)]
    for _ in range(passes):
        changed = False
        for k in range(B):
            # energy with σk = +1 minus with σk = -1
            d = -2.0 * (C @ Jr[k] + hr[k])
            for regs, energies, pos in touching[k]:
                idx = (C[:, regs] < 0).astype(np.int64) @ (1 << np.arange(regs.size))
                d += energies[idx & ~(1 << pos)] - energies[idx | (1 << pos)]
            new = np.where(d < 0, 1.0, np.where(d > 0, -1.0, C[:, k]))
            changed |= bool(np.any(new != C[:, k]))
            C[:, k] = new
        if not changed:
            break
    return C[int(np.argmin(energy(C)))]


def _refine_cells(Jc, h, s, nearest, fixed, shape, rings, sweeps, rounds=3, block_px=4):
    """Flip whole cells where that lowers the energy: a cell is a region, or the free pixels
    of one ``block_px`` square nearest to one region (``nearest``: each pixel's nearest
    region), their signs as completed. The energy of
    flipping any union of cells is exactly an Ising energy over the cells (``-σᵀCσ/2 -
    hcᵀσ``, ``C`` the couplings between cells of the signed field ``s``), minimised by
    :func:`_minimise_regions`; the free pixels are then swept again. This weighs the groups
    of free pixels that touch many regions, and undoes what the regions' choice and the
    pixel-by-pixel sweeps got wrong (a small torus's tube, mostly free pixels, whose parts
    only flip together)."""
    import scipy.sparse as sp

    n = s.size
    on = np.nonzero(s != 0)[0]
    # free pixels: by nearest region and block of block_px x block_px
    rr, cc = np.divmod(on, shape[1])
    blocks = ((rr // block_px) * (shape[1] // block_px + 1) + cc // block_px).astype(np.int64)
    key = np.where(fixed[on], nearest[on], (nearest[on] + 1) * (blocks.max() + 1) + blocks + nearest.max() + 1)
    _, inv = np.unique(key, return_inverse=True)
    cell = np.zeros(n, dtype=np.int64)
    cell[on] = inv
    B = int(inv.max()) + 1
    P = sp.csr_matrix((np.ones(on.size), (on, cell[on])), shape=(n, B))
    for _ in range(rounds):
        Ss = sp.diags(s)
        C = (P.T @ (Ss @ Jc @ Ss) @ P).toarray()
        np.fill_diagonal(C, 0.0)
        sig = _minimise_regions(C, P.T @ (s * h), [])
        if np.all(sig == sig[0]) and sig[0] > 0:
            break
        s = s * sig[cell]
        if rings is not None:
            s = _icm(rings[1], h, s, sweeps)
    return s


def resolve_signs(J, h, label, orient, mask, weight, min_region_weight=0.002, sweeps=10):
    """Minimise ``-sᵀJs/2 - hᵀs`` (see the module docstring) given regions of fixed internal
    orientation; returns the signs (flat, ±1 on the mask, 0 elsewhere).

    The regions are oriented jointly by the energy within and between them plus, for every
    group of free pixels between them, its energy once completed for each sign choice of the
    regions it touches (:func:`_gap_tables`): exactly by enumeration for up to
    :data:`EXACT_REGIONS` regions, otherwise by the best of many descents
    (:func:`_minimise_regions`).
    """
    import scipy.sparse as sp

    n = J.shape[0]
    m = mask.ravel()
    wf = weight.ravel()
    H, W = mask.shape
    rr, cc = np.divmod(np.arange(n), W)
    colour = (rr % 3) * 3 + (cc % 3)
    Jc = J.tocsr()
    K = int(label.max()) + 1 if (label >= 0).any() else 0
    region_of = np.full(n, -1, dtype=np.int64)
    fixed = np.zeros(n, dtype=bool)
    if K:
        rw = np.bincount(label[label >= 0], weights=wf[label >= 0], minlength=K)
        big = np.nonzero(rw >= min_region_weight * max(rw.sum(), 1e-300))[0]
        fixed = np.isin(label, big)
        # regions renumbered 0 .. B-1
        region_of[fixed] = np.searchsorted(big, label[fixed])
        B = big.size
    dist = (ndimage.distance_transform_cdt(~fixed.reshape(H, W), metric="chessboard").ravel()
            if fixed.any() else np.zeros(n, dtype=np.int64))
    if K:
        P = sp.csr_matrix((orient[fixed], (np.nonzero(fixed)[0], region_of[fixed])), shape=(n, B))
        Jr = (P.T @ Jc @ P).toarray()
        np.fill_diagonal(Jr, 0.0)
        hr = P.T @ h
        tables, many = _gap_tables(Jc, h, region_of, orient, (m & ~fixed).reshape(H, W), colour, dist)
        # each pixel's nearest region
        _, (ir, ic) = ndimage.distance_transform_edt(~fixed.reshape(H, W), return_indices=True)
        nearest = np.where(m, region_of[(ir * W + ic).ravel()], -1)
        pair_j, unary = _gap_couplings(Jc, h, region_of, orient, many, nearest, colour)
        for (a, b), v in pair_j.items():
            Jr[a, b] += v
            Jr[b, a] += v
        for a, v in unary.items():
            hr[a] += v
        sig = _minimise_regions(Jr, hr, tables)
    # the rest: iterated conditional modes in 3 x 3 colour classes (pixels of one class share
    # no coupling, which reaches two pixels along a line), from the fixed pixels outwards
    free = np.nonzero(m & ~fixed)[0]
    rings = _rings(Jc, free, dist, colour) if free.size else None
    s = np.zeros(n)
    if K:
        s[fixed] = orient[fixed] * sig[region_of[fixed]]
    if rings is not None:
        s = _complete(rings, h, s, sweeps)
    if K:
        s = _refine_cells(Jc, h, s, nearest, fixed, (H, W), rings, sweeps)
    return np.where(m, s, 0.0)


def _half(o, conf, mask):
    """The field on 2 x 2 blocks: the confidence-weighted mean of ``o ⊗ o`` (sign-free) turned
    back into an axis and magnitude, the mean confidence, blocks with two mask pixels."""
    H, W = mask.shape
    Hp, Wp = H + H % 2, W + W % 2
    pad = ((0, Hp - H), (0, Wp - W))
    m = np.pad(mask, pad).astype(float)
    c = np.pad(np.where(mask, conf, 0.0), pad)
    ox, oy = np.pad(o[..., 0], pad), np.pad(o[..., 1], pad)
    # doubled-angle vector v = |o|² (cos 2φ, sin 2φ): averaging it needs no sign
    v1, v2 = ox * ox - oy * oy, 2.0 * ox * oy

    def blocks(a):
        return a.reshape(Hp // 2, 2, Wp // 2, 2).sum(axis=(1, 3))

    w = blocks(c * m) + 1e-12
    cnt = blocks(m)
    V1, V2 = blocks(c * v1) / w, blocks(c * v2) / w
    mag2 = np.hypot(V1, V2)
    phi = 0.5 * np.arctan2(V2, V1)
    oc = np.sqrt(mag2)[..., None] * np.stack([np.cos(phi), np.sin(phi)], -1)
    mc = cnt >= 2
    return np.where(mc[..., None], oc, 0.0), np.where(mc, blocks(c) / np.maximum(cnt, 1), 0.0), mc


def _signs(o, th, conf, m, first, second, max_pixels):
    """Signs (H, W) of the representatives ``o``; large masks are solved on 2 x 2 blocks
    (recursively) and every pixel takes the sign that agrees with its block's signed field,
    interpolated."""
    if max_pixels is not None and m.sum() > max_pixels:
        oc, cc, mc = _half(o, conf, m)
        sc = _signs(oc, np.arcsin(np.clip(np.linalg.norm(oc, axis=-1), 0.0, 1.0)), cc, mc, first, second,
                    max_pixels)
        signed = np.where(mc[..., None], oc * sc[..., None], 0.0)
        from scipy import ndimage

        _, (ir, ic) = ndimage.distance_transform_edt(~mc, return_indices=True)
        H, W = m.shape
        r = (np.arange(H) - 0.5) / 2.0
        cgrid = (np.arange(W) - 0.5) / 2.0
        R, C = np.meshgrid(r, cgrid, indexing="ij")
        up = np.stack([ndimage.map_coordinates(signed[..., k][ir, ic], [R, C], order=1, mode="nearest")
                       for k in range(2)], -1)
        return np.where(m, np.where(np.sum(up * o, axis=-1) >= 0, 1.0, -1.0), 0.0)
    J = coupling_matrix(o, conf, m, first, second)
    h = contour_anchors(o, th, conf, m).ravel()
    label, orient = _regions(o, conf, m)
    weight = (conf * np.sin(th) ** 2).ravel()
    return resolve_signs(J, h, label, orient, m, weight).reshape(m.shape)


def resolve_azimuth_global(azimuth_mod_deg, zenith_deg, mask, confidence=None, first=1.0, second=1.0,
                           max_pixels=12000, return_info=False, min_evidence=3.0):
    """Azimuth in [0, 360) (degrees; NaN outside the mask) from the azimuth modulo 180°,
    the zenith and a per-pixel confidence (0-1, e.g. the normalised precision of the
    normal's image-plane part; default 1), by minimising the energy of the module docstring.

    Masks of more than ``max_pixels`` pixels are solved on 2 x 2 blocks (recursively): each
    pixel then takes the sign that agrees with its block's (interpolated) signed normal.

    With ``return_info``, also a dict: ``sign_by_prior``, the fraction of the mask's pixels
    in connected parts whose occluding-contour evidence (:func:`contour_anchors`) weighs less
    than ``min_evidence`` (about as many fully confident steep pixels): an open sheet, a
    shallow cap. There the global sign is the convex prior's; the mirror image ``z -> -z``
    fits the data as well.
    """
    m = np.asarray(mask, dtype=bool)
    if min(m.shape) < 3:
        # image gradients need three pixels: solve on the image framed by non-mask pixels
        pad = ((2, 2), (2, 2))
        conf_p = None if confidence is None else np.pad(np.asarray(confidence, dtype=np.float64), pad)
        out = resolve_azimuth_global(np.pad(np.asarray(azimuth_mod_deg, dtype=np.float64), pad),
                                     np.pad(np.asarray(zenith_deg, dtype=np.float64), pad), np.pad(m, pad),
                                     conf_p, first, second, max_pixels, return_info, min_evidence)
        crop = (slice(2, -2), slice(2, -2))
        return (out[0][crop], out[1]) if return_info else out[crop]
    phi = np.radians(np.nan_to_num(np.asarray(azimuth_mod_deg, dtype=np.float64)))
    th = np.radians(np.nan_to_num(np.asarray(zenith_deg, dtype=np.float64)))
    conf = np.ones(m.shape) if confidence is None else np.clip(np.nan_to_num(confidence), 0.0, 1.0)
    conf = np.where(m, conf, 0.0)
    o = np.sin(th)[..., None] * np.stack([np.cos(phi), np.sin(phi)], -1)
    o = np.where(m[..., None], o, 0.0)
    s = _signs(o, th, conf, m, first, second, max_pixels)
    az = np.where(s < 0, phi + np.pi, phi)
    az = np.where(m, np.mod(np.degrees(az), 360.0), np.nan)
    if not return_info:
        return az
    _, evidence = contour_anchors(o, th, conf, m, return_evidence=True)
    labels, count = ndimage.label(m)
    weight = np.bincount(labels[m], weights=evidence[m], minlength=count + 1)
    size = np.bincount(labels[m], minlength=count + 1)
    by_prior = float(size[1:][weight[1:] < min_evidence].sum() / max(int(m.sum()), 1))
    return az, {"sign_by_prior": by_prior}

