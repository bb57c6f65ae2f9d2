r"""A light BVH: spatially adaptive light selection in O(log N) per shading point.

The tree of Conty Estevez & Kulla (2018), with the importance bound and the split cost of
pbrt-v4's ``BVHLightSampler`` / ``LightBounds`` (re-implemented here, numpy for the build and
Dr.Jit for the traversal).

**What a node bounds.**  Every node holds the summed power Phi of its lights, an axis-aligned box
around them, and a cone of emission directions: an axis w, the half-angle theta_o that bounds the
lights' normals (or, for a point light, theta_o = pi) and the half-angle theta_e of emission
around any such normal (pi/2 for Lambertian emitters), plus a two-sided flag (then the cone bounds
+-w).  The **importance** of a node at a shading point x with normal n (pbrt-v4's
``LightBounds::Importance``) is

    I = Phi cos(theta') / max(d^2, r) * cos(max(theta_i - theta_b, 0)),

with d the distance from x to the power-weighted centre of the node's lights (pbrt-v4 takes the
box centre; the weighted centre ranks clusters better: the second moment of the light choice
for unshadowed direct light on the 1,024-light field fell from 1.83x to 1.60x the ideal's, mean
over 100 floor points, both with the box-centred sphere; selection by power alone: 38x), r the radius of the sphere around that
centre that holds the node's box (pbrt-v4's sphere is centred on the box, its radius the half
diagonal; one centre for both keeps the device record to 12 words, see :class:`DeviceTree`), the
clamp max(d^2, r) (pbrt's: a length, not its square, so nodes that contain x still rank their
children by distance), theta_b the half-angle that sphere subtends at x (pi inside it), with
theta_w the angle between the cone's axis and the direction from the centre to x,
theta' = max(theta_w - theta_o - theta_b, 0) the smallest angle between the cone and the
direction to x, and theta_i the angle between that
direction and the line of n (|cos|: the receiver may transmit).  I = 0 only when no point of the
sphere (and so of the box) can emit towards x within the cone (theta' >= theta_e + 1e-3 rad
of slack for float32); the receiver factor is floored at 1e-3, so a light that can contribute always has I > 0 and can be
chosen (the estimator stays unbiased without a defensive mixture).

**Traversal** (:meth:`DeviceTree.traverse`, :meth:`LightTreeSelection.choose`): from the root, the child c of a node is chosen with
probability I_c / (I_left + I_right), one uniform number rescaled after each decision; the pmf of
the light reached is the product of those ratios.  A symbolic Dr.Jit loop (one iteration per
level), so the kernel does not grow with the number of lights.  **The pmf of a given light** at a
point (:meth:`DeviceTree.pmf`, :meth:`LightTreeSelection.pmf_at`, for MIS of BSDF-sampled hits) walks the same root-to-leaf path,
read from the light's bit trail (bit k: right child at depth k; 64 bits in two words), evaluating
the same two importances per level in the same order, so it equals the probability of traversal.

**Which emitters are leaves.**  Every finite emitter is one leaf:

* an area emitter (Mitsuba's ``area`` on any shape) is **one leaf for the whole shape** (a
  Mitsuba emitter is one entity to Mitsuba's ``sample_direction``; splitting a mesh into triangles
  would need our own per-triangle sampling): its box is the shape's bounding box, its cone the
  shape's normal for ``rectangle`` and ``disk`` (one-sided: Mitsuba's area light emits on the
  front only), the cone of all face (and vertex, when present) normals of a mesh, taken
  two-sided because the orientation flags of a mesh are not read back (the full sphere when
  those normals do not fit in a cone), and the full sphere for curved shapes (sphere,
  cylinder, ...);
* point, spot and projector lights are point leaves (box = their position, full sphere of
  directions: the spot's cone is not used, which is conservative);
* infinite emitters (``constant``, ``envmap``, ``directional``) are chosen **outside the tree**:
  with probability p_inf = (their power) / (power of all emitters), the same share as
  ``light_selection=power`` gives them (pbrt-v4 gives them n_inf / (n_inf + 1), which spends half
  of the light samples of ``veach_mis`` on its faint environment), and among them by power;
  otherwise the tree.

Emitters of zero power are not in the tree and are never chosen (they add nothing).  If every
finite emitter has zero power (a power estimate that failed), all get power 1.

**Build** (:func:`build`): top-down, all nodes of a level at once in numpy (vectorised over the
lights, no Python loop over nodes), splitting each node at the minimum over 3 axes x 11 bucket
boundaries (12 buckets over the centroid bounds) of pbrt's surface-area-orientation cost
Phi * M_Omega(theta_o, theta_e) * area(box) * K_r (K_r = longest box extent / extent along the
axis), with one light per leaf.  To keep the build fast, nodes of at most 64 lights leave the
orientation measure out of the cost (their split is by area and power only: split quality
traded for build time), nodes of at most 8 lights are split at the median of
their longest centroid extent, and where every light of a level has the same cone (all point
or sphere lights, a ceiling of equal panels) the orientation measure drops out exactly.  Bucket cones are bounded by their mean axis and
the largest angle to it, unions of cones follow pbrt's ``Union(DirectionCone, DirectionCone)``.  A node
with no valid split (all centroids equal), or deeper than 40, is split at the median count, so
the depth stays below 64 for up to 2^24 lights.  Nodes are numbered level by level with the two
children adjacent, and flattened into Dr.Jit arrays (a 12-word record per node: the
weighted centre and the radius of a sphere around it that holds the box, rounded up in
float32, the cone, phi and the node's child index; :class:`DeviceTree`).

**Resampling** (``light_selection=ris``, :class:`ResampledTreeSelection`): the tree's bound is
loosest at its upper levels (a node's Phi / d^2 to its centre underrates a cluster that holds a
light close to x); drawing 4 candidates from the tree and keeping one in proportion to its own
leaf importance divided by its tree pmf removes most of that loss for one shadow ray.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from ..common import is_jit, luminance
from .light_selection import CANDIDATES, ONE_MINUS_EPS, LightSelection, emitter_powers, \
    rotated, rotated_2d

BUCKETS = 12
ORIENT_MIN = 64            # nodes of at most this many lights: SAH without the orientation
SMALL = 8                  # nodes of at most this many lights: split at the median
MEDIAN_DEPTH = 40          # deeper nodes are split at the median count
MAX_DEPTH = 64             # bit trail: two 32-bit words
COS_E_SLACK = 1e-3         # the emission-cone test keeps lights up to this much beyond it
RECEIVER_FLOOR = 1e-3      # smallest receiver factor (shading normals may see past the horizon)
LEAF = np.uint32(0x80000000)


# ---------------------------------------------------------------------------------------------
# numpy geometry of cones and bounds
def _norm(v):
    return np.sqrt(np.einsum("...i,...i->...", v, v))


def _angle_between(a, b):
    """Angle between unit vectors, accurate for small angles."""
    return 2.0 * np.arctan2(_norm(a - b), _norm(a + b))


def cone_union(wa, ca, wb, cb):
    """pbrt-v4's ``Union(DirectionCone a, DirectionCone b)``, vectorised: (w, cos theta) of the
    smallest cone (of that construction) around both.  cos = -1 is the entire sphere; an empty
    cone is passed as cos = +inf (returns the other one)."""
    wa, wb = np.asarray(wa, float), np.asarray(wb, float)
    ca, cb = np.asarray(ca, float), np.asarray(cb, float)
    empty_a, empty_b = ~np.isfinite(ca), ~np.isfinite(cb)
    ta = np.arccos(np.clip(ca, -1, 1))
    tb = np.arccos(np.clip(cb, -1, 1))
    td = _angle_between(wa, wb)
    to = 0.5 * (ta + td + tb)
    tr = to - ta
    wr = np.cross(wa, wb)
    lr = _norm(wr)
    k = wr / np.maximum(lr, 1e-30)[..., None]
    # Rodrigues: rotate wa about k by tr
    ct, st = np.cos(tr)[..., None], np.sin(tr)[..., None]
    kw = np.einsum("...i,...i->...", k, wa)[..., None]
    w = wa * ct + np.cross(k, wa) * st + k * kw * (1 - ct)
    w /= np.maximum(_norm(w), 1e-30)[..., None]
    c = np.cos(to)
    full = (to >= math.pi) | (lr == 0)
    w = np.where(full[..., None], [0.0, 0.0, 1.0], w)
    c = np.where(full, -1.0, c)
    a_covers = np.minimum(td + tb, math.pi) <= ta
    b_covers = np.minimum(td + ta, math.pi) <= tb
    pick_a = (a_covers | empty_b) & ~empty_a
    pick_b = (b_covers | empty_a) & ~pick_a
    w = np.where(pick_a[..., None], wa, np.where(pick_b[..., None], wb, w))
    c = np.where(pick_a, ca, np.where(pick_b, cb, c))
    return w, c


def m_omega(cos_o, cos_e):
    """pbrt-v4's orientation measure of a cone (theta_o, theta_e)."""
    cos_o = np.clip(cos_o, -1, 1)
    t_o, t_e = np.arccos(cos_o), np.arccos(np.clip(cos_e, -1, 1))
    t_w = np.minimum(t_o + t_e, math.pi)
    sin_o = np.sqrt(np.maximum(1 - cos_o * cos_o, 0))
    return (2 * math.pi * (1 - cos_o)
            + math.pi / 2 * (2 * t_w * sin_o - np.cos(t_o - 2 * t_w) - 2 * t_o * sin_o + cos_o))


def _area(lo, hi):
    """Surface area of boxes; 0 for the empty box (lo = +inf, hi = -inf)."""
    d = np.maximum(hi - lo, 0)
    return 2 * (d[..., 0] * d[..., 1] + d[..., 1] * d[..., 2] + d[..., 2] * d[..., 0])


def mean_axis_cone(w, cos_o, group, n_groups, theta_o=None, exact=True, count=None):
    """A cone around the axes of every group (cos = +inf for empty groups): the normalised sum
    of the member axes, widened to the largest angle to a member plus its own theta_o (the
    entire sphere when the sum vanishes).  ``theta_o``: arccos(cos_o) if already known (a
    number if the same for all); ``exact`` False: the angle to a member by arccos of the dot
    product, cheaper, off by up to about 1.5e-8 rad either way (for the build's split cost,
    which only compares splits); ``count``: the members of each group, if known."""
    s = np.zeros((n_groups, 3))
    for k in range(3):
        s[:, k] = np.bincount(group, weights=w[:, k], minlength=n_groups)
    if count is None:
        count = np.bincount(group, minlength=n_groups)
    length = _norm(s)
    ok = length > 1e-6 * np.maximum(count, 1)
    axis = np.where(ok[:, None], s / np.maximum(length, 1e-30)[:, None], [0.0, 0.0, 1.0])
    if theta_o is None:
        theta_o = np.arccos(np.clip(cos_o, -1, 1))
    if not exact and np.ndim(theta_o) == 0:
        # one theta_o for all (area lights: 0): the widest angle is that of the smallest dot
        # product (arccos decreases), so one arccos per group instead of one per member
        ax = axis.T.copy()
        dot = np.take(ax[0], group)
        dot *= w[:, 0]
        for k in (1, 2):
            t = np.take(ax[k], group)
            t *= w[:, k]
            dot += t
        least = np.ones(n_groups)
        np.minimum.at(least, group, dot)
        widest = np.arccos(np.clip(least, -1, 1)) + theta_o
        widest[count == 0] = 0.0
    else:
        ang = (_angle_between(axis[group], w) if exact else
               np.arccos(np.clip(np.einsum("ij,ij->i", axis[group], w), -1, 1))) + theta_o
        widest = np.zeros(n_groups)
        np.maximum.at(widest, group, ang)
    cos = np.where(widest >= math.pi, -1.0, np.cos(np.minimum(widest, math.pi)))
    cos = np.where(ok, cos, -1.0)
    cos = np.where(count > 0, cos, np.inf)
    return axis, cos


# ---------------------------------------------------------------------------------------------
class Tree:
    """The flattened tree (numpy, float64): per node box, cone, power, two-sided flag and
    ``info`` (LEAF | light for a leaf, else the index of the first of the two children); per
    light (index into the arrays given to :func:`build`) its depth and bit trail."""

    def __init__(self, n_nodes, n_lights):
        self.lo = np.zeros((n_nodes, 3))
        self.hi = np.zeros((n_nodes, 3))
        self.w = np.zeros((n_nodes, 3))
        self.cos_o = np.zeros(n_nodes)
        self.cos_e = np.zeros(n_nodes)
        self.phi = np.zeros(n_nodes)
        self.two = np.zeros(n_nodes, bool)
        self.info = np.zeros(n_nodes, np.uint32)
        self.level = np.zeros(n_nodes, np.int64)
        self.depth = np.zeros(n_lights, np.uint32)
        self.trail = np.zeros(n_lights, np.uint64)
        self.node_of = np.zeros(n_lights, np.int64)
        self.centre = np.zeros((n_nodes, 3))

    @property
    def size(self):
        return len(self.phi)


def build(lo, hi, w, cos_o, cos_e, two, phi) -> Tree:
    """Build the light BVH over N >= 1 lights given by numpy arrays: box corners lo, hi (N, 3),
    cone axes w (N, 3), cos theta_o, cos theta_e, two-sided flags and powers (N,)."""
    lo, hi, w = (np.asarray(a, float).reshape(-1, 3) for a in (lo, hi, w))
    cos_o, cos_e, phi = (np.asarray(a, float).ravel() for a in (cos_o, cos_e, phi))
    two = np.asarray(two, bool).ravel()
    n = len(phi)
    if n == 0:
        raise ValueError("light tree: no lights to build over")
    tree = Tree(2 * n - 1, n)
    centroid = 0.5 * (lo + hi)
    perm = np.arange(n)
    # every light's attributes in one column (rows: ROW), kept in the order of perm, so a
    # level reads them in order instead of gathering seven arrays at random (the gathers
    # were a third of the build), and an attribute's values lie contiguous for the
    # per-bucket reductions (strided, they cost twice as much)
    rows_all = np.ascontiguousarray(np.concatenate(
        [lo, hi, w, centroid, phi[:, None], cos_o[:, None], cos_e[:, None],
         np.arccos(np.clip(cos_o, -1, 1))[:, None]], axis=1).T)
    crow = ROW["c"]
    # the active segments of this level: perm[start:end] are the lights of node `node`
    start, end = np.array([0]), np.array([n])
    node = np.array([0])
    trail = np.array([0], np.uint64)
    next_id, level = 1, 0
    while len(start):
        length = end - start
        tree.level[node] = level
        # leaves
        leaf = length == 1
        if leaf.any():
            j = perm[start[leaf]]
            tree.info[node[leaf]] = LEAF | j.astype(np.uint32)
            tree.depth[j] = level
            tree.trail[j] = trail[leaf]
            tree.node_of[j] = node[leaf]
        start, end, node, trail, length = (a[~leaf] for a in (start, end, node, trail, length))
        if not len(start):
            break
        S = len(start)
        offs = np.concatenate([[0], np.cumsum(length)[:-1]])
        pos = np.repeat(start - offs, length) + np.arange(length.sum())
        ids = perm[pos]
        if crow != slice(0, 3) and length.max() <= SMALL:
            # from here on every split is at the median: only the centroids are read
            rows_all, crow = np.ascontiguousarray(rows_all[crow]), slice(0, 3)
        # until the first leaf every light is active and pos is 0..n-1: no gather needed
        rows = rows_all if len(pos) == n else rows_all[:, pos]
        seg = np.repeat(np.arange(S), length)
        c = rows[crow]                                                  # (3, lights)
        cmin = np.minimum.reduceat(c, offs, axis=1).T                   # (S, 3)
        cmax = np.maximum.reduceat(c, offs, axis=1).T
        # SAOH over the nodes of more than SMALL lights; the others (and nodes without a valid
        # split) at the median of their longest centroid extent
        big = length > SMALL
        split_k = np.full(S, -1)
        split_dim = np.full(S, -1)
        for group, orient in ((length > ORIENT_MIN, True),
                              (big & (length <= ORIENT_MIN), False)):
            if not group.any() or level >= MEDIAN_DEPTH:
                continue
            bs = np.nonzero(group)[0]
            if len(bs) == S:
                k, d = _best_splits(rows, seg, S, cmin, cmax, length, orient)
            else:
                sel = group[seg]
                remap = np.cumsum(group) - 1
                k, d = _best_splits(rows[:, sel], remap[seg[sel]], len(bs), cmin[bs], cmax[bs],
                                    length[group], orient)
            split_k[bs], split_dim[bs] = k, d
        use_sah = split_k >= 0
        sd = np.where(use_sah, split_dim, np.argmax(cmax - cmin, axis=1))
        sds = sd[seg]
        coord = np.where(sds == 0, c[0], np.where(sds == 1, c[1], c[2]))
        ext = (cmax - cmin)[np.arange(S), sd]
        lo_sd = cmin[np.arange(S), sd]
        b = _bucket(coord, lo_sd, ext, length) if use_sah.any() else 0
        # lights of median-split nodes in order of their coordinate (src: where each position
        # takes its light from), then the first half left
        med = ~use_sah[seg]
        src = None
        if med.any():
            m = np.nonzero(med)[0]
            # one sort key: the segment plus the coordinate's place in its span, in [0, 0.5]
            # (a stable float sort is ten times faster than np.lexsort)
            sm = seg[m]
            o = m[np.argsort(sm + 0.5 * (coord[m] - lo_sd[sm]) / np.where(ext > 0, ext, 1.0)[sm],
                             kind="stable")]
            src = np.arange(len(ids))
            src[m] = o
        rank = np.arange(len(ids)) - offs[seg]
        side = np.where(use_sah[seg], b > split_k[seg], rank >= (length // 2)[seg])
        order = np.argsort(2 * seg + side, kind="stable")
        if src is not None:
            order = src[order]
        perm[pos] = ids[order]
        if len(pos) == n:
            rows_all = rows[:, order]
        else:
            rows_all[:, pos] = rows[:, order]
        n_left = np.bincount(seg, weights=~side, minlength=S).astype(np.int64)
        # children: adjacent, numbered level by level
        first = next_id + 2 * np.arange(S)
        tree.info[node] = first.astype(np.uint32)
        next_id += 2 * S
        bit = np.uint64(1) << np.uint64(level)
        mid = start + n_left
        start = np.stack([start, mid], 1).ravel()
        end = np.stack([mid, end], 1).ravel()
        node = np.stack([first, first + 1], 1).ravel()
        trail = np.stack([trail, trail | bit], 1).ravel()
        level += 1
        if level > MAX_DEPTH:
            raise RuntimeError("light tree: deeper than 64 levels")
    # bounds bottom-up: leaves from their light, interior nodes as the union of their children
    is_leaf = (tree.info & LEAF) != 0
    lf = tree.node_of                                   # light j's leaf: lf[j]
    tree.lo[lf], tree.hi[lf], tree.w[lf] = lo, hi, w
    tree.cos_o[lf], tree.cos_e[lf], tree.phi[lf], tree.two[lf] = cos_o, cos_e, phi, two
    tree.centre[lf] = centroid
    for lev in range(int(tree.level.max()), -1, -1):
        nd = np.nonzero((tree.level == lev) & ~is_leaf)[0]
        if not len(nd):
            continue
        a = tree.info[nd].astype(np.int64)
        b2 = a + 1
        tree.lo[nd] = np.minimum(tree.lo[a], tree.lo[b2])
        tree.hi[nd] = np.maximum(tree.hi[a], tree.hi[b2])
        tree.phi[nd] = tree.phi[a] + tree.phi[b2]
        pa, pb = tree.phi[a, None], tree.phi[b2, None]
        tree.centre[nd] = ((pa * tree.centre[a] + pb * tree.centre[b2])
                           / np.maximum(tree.phi[nd], 1e-300)[:, None])
        tree.two[nd] = tree.two[a] | tree.two[b2]
        tree.cos_e[nd] = np.minimum(tree.cos_e[a], tree.cos_e[b2])
        w2, c2 = tree.w[b2], tree.cos_o[b2]
        tree.w[nd], tree.cos_o[nd] = cone_union(tree.w[a], tree.cos_o[a], w2, c2)
    return tree


def _reduce_at(ufunc, init, n, key, v):
    """ufunc.at over the rows of v grouped by key into n rows, a column at a time (the 1-D
    ufunc.at is much faster than the 2-D one)."""
    out = np.full((n, v.shape[1]), init)
    for k in range(v.shape[1]):
        col = np.full(n, init)
        ufunc.at(col, key, v[:, k])
        out[:, k] = col
    return out


def _bucket(c, cmin, ext, counts):
    """The bucket (0 .. BUCKETS - 1) of each centroid coordinate c: ``counts[s]`` consecutive
    lights of each segment s, whose centroids span cmin + [0, ext] (arrays of segments indexed
    along their first axis, transposed if c is (3, lights)); the segments' values are repeated
    over their lights (cheaper than a gather by segment)."""
    ext = np.where(ext > 0, ext, 1.0)
    axis = 1 if c.ndim == 2 else 0
    cmin, ext = (np.repeat(a.T if c.ndim == 2 else a, counts, axis=axis) for a in (cmin, ext))
    b = c - cmin
    b *= BUCKETS
    b /= ext
    b = b.astype(np.int64)                              # c >= cmin: truncation is floor
    return np.minimum(b, BUCKETS - 1, out=b)


#: the rows of the build's attribute table (one column a light) in :func:`build`
ROW = {"lo": slice(0, 3), "hi": slice(3, 6), "w": slice(6, 9), "c": slice(9, 12), "phi": 12,
       "cos_o": 13, "cos_e": 14, "theta_o": 15}


def _best_splits(rows, seg, S, cmin, cmax, counts, orient=True):
    """Per segment: (bucket boundary k, axis) of the cheapest SAOH split, k = -1 for none;
    ``rows``: the segments' lights, one column each (rows: ROW), segment seg[i] for light i,
    ``counts[s]`` lights of segment s, consecutive; ``cmin``, ``cmax`` (S, 3): the bounds of
    their centroids; ``orient`` False: without the orientation measure (surface area and power
    only)."""
    lo_i, hi_i, w_i = (rows[ROW[k]].T for k in ("lo", "hi", "w"))
    phi_i, co_i, ce_i, theta_i = (rows[ROW[k]] for k in ("phi", "cos_o", "cos_e", "theta_o"))
    ext = cmax - cmin                                                   # (S, 3)
    nb = S * BUCKETS
    # one cone for every light (all point lights, or flat lights facing the same way): the
    # orientation measure is the same for every split and drops out of the comparison
    same_cone = not orient or all(r.min() == r.max() for r in (*w_i.T, co_i, ce_i))
    theta = theta_i[0] if theta_i.min() == theta_i.max() else theta_i
    same_ce = ce_i.min() == ce_i.max()
    # the buckets' contents along each axis, index [axis, bucket, segment] (a bucket of
    # every segment in one block, for the sweep below)
    # (an axis along which no segment's centroids extend has no valid split: its buckets are
    # left empty, not counted; lights in a plane, such as a ceiling of panels, skip a third)
    dims = [d for d in range(3) if (ext[:, d] > 0).any()]
    if not dims:
        return np.full(S, -1), np.full(S, -1)
    b3 = _bucket(rows[ROW["c"]], cmin, ext, counts)                     # (3, lights)
    count, bphi = np.zeros((3, nb)), np.zeros((3, nb))
    blo, bhi = np.full((3, nb, 3), np.inf), np.full((3, nb, 3), -np.inf)
    if not same_cone:
        bw, bco, bce = np.zeros((3, nb, 3)), np.full((3, nb), np.inf), np.ones((3, nb))
    for dim in dims:
        key = b3[dim] * S + seg
        count[dim] = np.bincount(key, minlength=nb)
        bphi[dim] = np.bincount(key, weights=phi_i, minlength=nb)
        blo[dim] = _reduce_at(np.minimum, np.inf, nb, key, lo_i)
        bhi[dim] = _reduce_at(np.maximum, -np.inf, nb, key, hi_i)
        if not same_cone:
            bw[dim], bco[dim] = mean_axis_cone(w_i, co_i, key, nb, theta_o=theta, exact=False,
                                               count=count[dim])
            bce[dim] = (np.where(count[dim] > 0, ce_i[0], 1.0) if same_ce else
                        _reduce_at(np.minimum, 1.0, nb, key, ce_i[:, None])[:, 0])
    count, bphi = (a.reshape(3, BUCKETS, S) for a in (count, bphi))
    blo, bhi = (a.reshape(3, BUCKETS, S, 3) for a in (blo, bhi))
    diag = bhi[dims[0]].max(axis=0) - blo[dims[0]].min(axis=0)          # the nodes' boxes
    if not same_cone:
        bco, bce = bco.reshape(3, BUCKETS, S), bce.reshape(3, BUCKETS, S)
        bw = bw.reshape(3, BUCKETS, S, 3)

    # cost of the union of buckets 0..i (left) and of buckets i+1..last (right) for every
    # boundary i: one sweep over the six (axis, direction) pairs at once, [pair, segment, i]
    def step(a, i):
        """Bucket i of the three axes sweeping up, bucket last - i sweeping down."""
        return np.concatenate([a[:, i], a[:, BUCKETS - 1 - i]])
    out = np.zeros((6, S, BUCKETS - 1))
    acc_lo = np.full((6, S, 3), np.inf)
    acc_hi = np.full((6, S, 3), -np.inf)
    acc_w = np.broadcast_to([0.0, 0.0, 1.0], (6, S, 3))
    acc_c = np.full((6, S), np.inf)
    acc_phi = np.zeros((6, S))
    acc_ce = np.ones((6, S))
    for i in range(BUCKETS - 1):
        acc_lo = np.minimum(acc_lo, step(blo, i))
        acc_hi = np.maximum(acc_hi, step(bhi, i))
        acc_phi = acc_phi + step(bphi, i)
        area = _area(acc_lo, acc_hi)
        if same_cone:
            out[:, :, i] = acc_phi * area
            continue
        acc_ce = np.minimum(acc_ce, step(bce, i))
        acc_w, acc_c = cone_union(acc_w, acc_c, step(bw, i), step(bco, i))
        cc = np.where(np.isfinite(acc_c), acc_c, 1.0)
        out[:, :, i] = acc_phi * m_omega(cc, acc_ce) * area
    left, right = out[:3], out[3:, :, ::-1]
    n_left = np.cumsum(count, axis=1)[:, :-1].transpose(0, 2, 1)        # (3, S, boundary)
    total = count.sum(1)[:, :, None]
    dmax = diag.max(1)
    kr = dmax / np.maximum(diag.T, 1e-12 * np.maximum(dmax, 1e-30))    # (3, S)
    cost = (left + right) * kr[:, :, None]
    ok = (n_left > 0) & (n_left < total) & (ext.T[:, :, None] > 0) & ~np.isnan(cost)
    cost = np.where(ok, cost, np.inf)
    # the first cheapest (axis, boundary), axes in order x, y, z
    flat = cost.transpose(1, 0, 2).reshape(S, -1)
    j = np.argmin(flat, axis=1)
    none = ~np.isfinite(flat[np.arange(S), j])
    best_d = np.where(none, -1, j // (BUCKETS - 1))
    best_k = np.where(none, -1, j % (BUCKETS - 1))
    return best_k, best_d


# ---------------------------------------------------------------------------------------------
def _up(x):
    return np.nextafter(x.astype(np.float32), np.float32(np.inf))


def reservoir_step(w, w_sum, v):
    """One candidate of weight w into a streaming reservoir read by one uniform v: (whether it
    replaces the kept one, with probability w / (w_sum + w); the new sum; v rescaled so that it
    stays uniform given the decision)."""
    w_sum = w_sum + w
    q = dr.select(w > 0, w / dr.select(w > 0, w_sum, 1.0), 0.0)
    take = (w > 0) & (v < q)
    v = dr.select(take, v / dr.select(take, q, 1.0),
                  (v - q) / dr.select(take | (q >= 1.0), 1.0, 1.0 - q))
    return take, w_sum, dr.minimum(v, ONE_MINUS_EPS)


class DeviceTree:
    """The tree in Dr.Jit arrays (numpy arrays in scalar variants), with the importance bound,
    the traversal and the root-to-leaf pmf."""

    # one record of 12 words per node, read as three 4-wide (packet) gathers: the gathers are
    # the traversal's cost (a level's time grows with the bytes read, not the arithmetic), so
    # the record holds only what the bound uses: the power-weighted centre c of the node's
    # lights and the radius r of a sphere around c that holds the node's box (the bound's
    # only geometry), the cone (axis w, cos_o, cos_e), phi (< 0: two-sided) and the node's own
    # ``info`` (LEAF | light, or its first child), so that a level reads its two children and
    # nothing else.  One choice on the 4,096-light field, 2^20 points: median 49-83 ns, against
    # 141 ns with a 16-word record (box, centre, cone) and a separate gather of ``info``; an
    # 8-word record (the cone in 16-bit codes) was not measurably faster (its decoding)
    FIELDS = ("cx", "cy", "cz", "r", "wx", "wy", "wz", "cos_o", "cos_e", "phi", "info", "pad")

    def __init__(self, tree: Tree):
        cos_o = np.clip(tree.cos_o, -1, 1).astype(np.float32)
        centre = tree.centre.astype(np.float32)
        # the farthest corner of the (float64) box from the (float32) centre, rounded up
        c64 = centre.astype(np.float64)
        far = np.maximum(tree.hi - c64, c64 - tree.lo)
        r = np.sqrt((far ** 2).sum(-1))
        r = _up(r * (1 + 1e-6))
        cols = dict(cx=centre[:, 0], cy=centre[:, 1], cz=centre[:, 2], r=r,
                    wx=tree.w[:, 0], wy=tree.w[:, 1], wz=tree.w[:, 2], cos_o=cos_o,
                    cos_e=tree.cos_e, phi=np.where(tree.two, -tree.phi, tree.phi))
        cols = {k: np.asarray(v, np.float32) for k, v in cols.items()}
        self.size = tree.size
        self.root_leaf = bool(tree.info[0] & LEAF)
        trail_lo = (tree.trail & np.uint64(0xFFFFFFFF)).astype(np.uint32)
        trail_hi = (tree.trail >> np.uint64(32)).astype(np.uint32)
        if is_jit():
            packed = np.zeros((self.size, len(self.FIELDS)), np.float32)
            for k, name in enumerate(self.FIELDS[:10]):
                packed[:, k] = cols[name]
            packed[:, 10] = tree.info.astype(np.uint32).view(np.float32)
            self.packed = mi.Float(packed.ravel())
            self.info = mi.UInt32(tree.info)
            self.depth = mi.UInt32(tree.depth)
            self.trail_lo, self.trail_hi = mi.UInt32(trail_lo), mi.UInt32(trail_hi)
            # opaque: the same kernel whether or not the arrays were evaluated when traced
            # (a one-light tree's arrays would otherwise enter the first trace as literals and
            # the second render would compile again)
            dr.make_opaque(self.packed, self.info, self.depth, self.trail_lo, self.trail_hi)
        else:
            self.col = cols
            self.info, self.depth = tree.info, tree.depth
            self.trail_lo, self.trail_hi = trail_lo, trail_hi

    def _get(self, arr, idx, dtype=None, active=True):
        if is_jit():
            return dr.gather(dtype or mi.Float, arr, idx, active)
        return (int if dtype is mi.UInt32 else float)(arr[int(idx)])

    def _record(self, node, active):
        """The fields of ``node``'s record (``info`` a UInt32 / int)."""
        if is_jit():
            q = [dr.gather(mi.Vector4f, self.packed, node * 3 + k, active) for k in range(3)]
            g = {name: q[k // 4][k % 4] for k, name in enumerate(self.FIELDS[:10])}
            g["info"] = dr.reinterpret_array(mi.UInt32, q[2][2])
        else:
            g = {k: float(v[int(node)]) for k, v in self.col.items()}
            g["info"] = int(self.info[int(node)])
        return g

    def importance(self, g, p, n, active=True):
        """pbrt-v4's LightBounds::Importance of the node whose record is ``g`` at point p
        with surface normal n, its bounding sphere (centre c, radius r) standing for its box."""
        c = mi.Point3f(g["cx"], g["cy"], g["cz"])
        r = g["r"]
        d = p - c
        d2 = dr.squared_norm(d)
        r2 = r * r
        inv = dr.rsqrt(dr.maximum(d2, 1e-30))
        wi = d * inv                                   # from the light towards p
        cos_w = dr.dot(mi.Vector3f(g["wx"], g["wy"], g["wz"]), wi)
        phi = g["phi"]
        cos_w = dr.select(phi < 0, dr.abs(cos_w), cos_w)
        sin_w = dr.safe_sqrt(1.0 - cos_w * cos_w)
        # half-angle subtended by the bounding sphere (whole sphere inside it)
        inside = d2 < r2
        cos_b = dr.select(inside, -1.0, dr.safe_sqrt(1.0 - r2 / dr.maximum(d2, 1e-30)))
        sin_b = dr.select(inside, 0.0, dr.safe_sqrt(1.0 - cos_b * cos_b))
        cos_o = g["cos_o"]
        sin_o = dr.safe_sqrt(1.0 - cos_o * cos_o)
        # theta_x = max(theta_w - theta_o, 0); theta' = max(theta_x - theta_b, 0)
        cos_x = dr.select(cos_w > cos_o, 1.0, cos_w * cos_o + sin_w * sin_o)
        sin_x = dr.select(cos_w > cos_o, 0.0, sin_w * cos_o - cos_w * sin_o)
        cos_p = dr.select(cos_x > cos_b, 1.0, cos_x * cos_b + sin_x * sin_b)
        # the distance is taken to the power-weighted centre of the node's lights (pbrt-v4:
        # the box centre), which ranks clusters better (module docstring); pbrt-v4's clamp
        # at the bound's radius (a length, not its square) keeps it finite
        inv_d2 = dr.rcp(dr.maximum(dr.maximum(d2, r), 1e-12))
        imp = dr.abs(phi) * dr.maximum(cos_p, RECEIVER_FLOOR) * inv_d2
        imp = dr.select(cos_p > g["cos_e"] - COS_E_SLACK, imp, 0.0)
        cos_i = dr.abs(dr.dot(wi, n))
        sin_i = dr.safe_sqrt(1.0 - cos_i * cos_i)
        cos_pi = dr.select(cos_i > cos_b, 1.0, cos_i * cos_b + sin_i * sin_b)
        has_n = dr.squared_norm(n) > 0
        imp = imp * dr.select(has_n, dr.maximum(cos_pi, RECEIVER_FLOOR), 1.0)
        return dr.select(active, imp, 0.0)

    def _children(self, c0, p, n, active):
        """The importances of the children c0, c0 + 1 and their ``info``."""
        g0, g1 = self._record(c0, active), self._record(c0 + 1, active)
        return (self.importance(g0, p, n, active), self.importance(g1, p, n, active),
                g0["info"], g1["info"])

    @dr.syntax
    def traverse(self, p, n, u, active=True):
        """Choose a light: (light index, pmf, importance of its leaf at (p, n)); pmf 0 (and
        index 0) where every importance on the way is 0 or the lane is inactive (a one-light
        tree's leaf importance is 1: it is never compared with another)."""
        pmf = mi.Float(1.0)
        leaf_imp = mi.Float(1.0)
        u = mi.Float(u)
        active = mi.Bool(active)
        info = self._get(self.info, mi.UInt32(0), mi.UInt32, active)     # the root's
        go = active & ((info & int(LEAF)) == 0)
        while dr.hint(go, label="light tree: traverse"):
            i0, i1, f0, f1 = self._children(info, p, n, go)
            total = i0 + i1
            ok = total > 0
            p0 = i0 / dr.select(ok, total, 1.0)
            left = u < p0
            chosen = dr.select(left, i0, i1)
            leaf_imp = chosen
            pmf = dr.select(ok, pmf * (chosen / dr.select(ok, total, 1.0)), 0.0)
            u = dr.select(left, u / dr.select(left, p0, 1.0),
                          (u - p0) / dr.select(left, 1.0, 1.0 - p0))
            u = dr.minimum(u, ONE_MINUS_EPS)
            info = dr.select(left, f0, f1)
            go = go & ok & ((info & int(LEAF)) == 0)
        light = info & int(~LEAF & 0xFFFFFFFF)
        pmf = dr.select(active & ((info & int(LEAF)) != 0), pmf, 0.0)
        return dr.select(pmf > 0, light, 0), pmf, leaf_imp

    @dr.syntax
    def resample(self, p, n, u, v, m, active=True):
        """Resampled choice among ``m`` traversals (:class:`ResampledTreeSelection`): (light,
        pmf, ratio), ``ratio`` = pmf(Y) (1/m) sum w / p^(Y), the factor that turns the plain
        tree weight 1 / pmf(Y) into the resampled one (1 where nothing was picked)."""
        active = mi.Bool(active)
        u, v = mi.Float(u), mi.Float(v)
        k = mi.UInt32(0)
        w_sum = mi.Float(0.0)
        y, p_y, h_y = mi.UInt32(0), mi.Float(0.0), mi.Float(1.0)
        while dr.hint(k < m, label="light tree: candidates"):
            light, pmf, imp = self.traverse(p, n, rotated(u, k, m), active)
            w = dr.select(pmf > 0, imp / dr.select(pmf > 0, pmf, 1.0), 0.0)
            take, w_sum, v = reservoir_step(w, w_sum, v)
            y = dr.select(take, light, y)
            p_y = dr.select(take, pmf, p_y)
            h_y = dr.select(take, imp, h_y)
            k += 1
        ok = active & (p_y > 0)
        ratio = dr.select(ok, p_y * w_sum / (m * dr.select(ok, h_y, 1.0)), 1.0)
        return dr.select(ok, y, 0), dr.select(ok, p_y, 0.0), ratio

    @dr.syntax
    def pmf(self, light, p, n, active=True):
        """Probability that :meth:`traverse` at (p, n) picks ``light``, by walking its bit trail
        from the root."""
        active = mi.Bool(active)
        depth = self._get(self.depth, light, mi.UInt32, active)
        lo = self._get(self.trail_lo, light, mi.UInt32, active)
        hi = self._get(self.trail_hi, light, mi.UInt32, active)
        info = self._get(self.info, mi.UInt32(0), mi.UInt32, active)     # the root's
        pmf = mi.Float(1.0)
        k = mi.UInt32(0)
        go = active & (k < depth)
        while dr.hint(go, label="light tree: pmf"):
            i0, i1, f0, f1 = self._children(info, p, n, go)
            total = i0 + i1
            ok = total > 0
            word = dr.select(k < 32, lo, hi)
            right = ((word >> (k & 31)) & 1) == 1
            chosen = dr.select(right, i1, i0)
            pmf = dr.select(ok, pmf * (chosen / dr.select(ok, total, 1.0)), 0.0)
            info = dr.select(right, f1, f0)
            k += 1
            go = go & ok & (k < depth)
        return dr.select(active, pmf, 0.0)


# ---------------------------------------------------------------------------------------------
# the scene's lights as leaves
INFINITE, TREE, NONE = 0, 1, 2


def _mesh_cone(shape):
    """(axis, cos theta_o) of a cone around the face normals (and vertex normals, if any) of a
    mesh, to be used two-sided; cos = -1 (entire sphere) when they do not fit."""
    try:
        v = np.array(shape.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
        f = np.array(shape.faces_buffer(), dtype=np.int64).reshape(-1, 3)
    except Exception:    # not a triangle mesh we can read
        return np.array([0.0, 0.0, 1.0]), -1.0
    nrm = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    length = _norm(nrm)
    nrm = nrm[length > 0] / length[length > 0][:, None]
    if shape.has_vertex_normals():
        vn = np.array(shape.vertex_normals_buffer(), dtype=np.float64).reshape(-1, 3)
        ln = _norm(vn)
        nrm = np.concatenate([nrm, vn[ln > 0] / ln[ln > 0][:, None]])
    if not len(nrm):
        return np.array([0.0, 0.0, 1.0]), -1.0
    # two-sided: orient every normal to the hemisphere of the first one, then bound them
    nrm = np.where((nrm @ nrm[0] < 0)[:, None], -nrm, nrm)
    axis, cos = mean_axis_cone(nrm, np.ones(len(nrm)), np.zeros(len(nrm), np.int64), 1)
    return axis[0], float(cos[0])


def light_leaves(scene, emitters, power, first_normal):
    """Per emitter: its kind (INFINITE, TREE, NONE = zero power) and leaf bounds (numpy):
    box lo, hi, cone axis w, cos theta_o, cos theta_e, two-sided flag."""
    n = len(emitters)
    kind = np.full(n, TREE)
    lo, hi = np.zeros((n, 3)), np.zeros((n, 3))
    w = np.tile([0.0, 0.0, 1.0], (n, 1))
    cos_o, cos_e = np.full(n, -1.0), np.zeros(n)
    two = np.zeros(n, bool)
    point_like = []
    flat = {int(mi.ShapeType.Rectangle), int(mi.ShapeType.Disk)}
    for j, e in enumerate(emitters):
        if mi.has_flag(e.flags(), mi.EmitterFlags.Infinite):
            kind[j] = INFINITE
            continue
        shape = e.get_shape()
        if shape is None:
            point_like.append(j)
            continue
        box = shape.bbox()
        lo[j], hi[j] = np.array(box.min, float).ravel(), np.array(box.max, float).ravel()
        st = int(shape.shape_type())
        if st in flat:                           # one normal, emission on its front side
            w[j], cos_o[j] = first_normal[j], 1.0
        elif st == int(mi.ShapeType.Mesh):
            w[j], cos_o[j] = _mesh_cone(shape)
            two[j] = True
    if point_like:
        # positions of point, spot and projector lights: where they send light from
        idx = np.array(point_like)
        bs = scene.bbox().bounding_sphere()
        far = (np.array(bs.center, float).ravel()
               + [0.0, 0.0, 2 * max(float(np.array(bs.radius).ravel()[0]), 1.0)])
        if is_jit():
            it = dr.zeros(mi.Interaction3f, len(idx))
            it.p = mi.Point3f(*[float(x) for x in far])
            em = dr.gather(mi.EmitterPtr, scene.emitters_dr(), mi.UInt32(idx.astype(np.uint32)))
            ds, _ = em.sample_direction(it, mi.Point2f(0.5, 0.5), True)
            pos = np.array(ds.p, dtype=np.float64).reshape(3, -1).T
        else:
            it = dr.zeros(mi.Interaction3f)
            it.p = mi.Point3f(*[float(x) for x in far])
            pos = np.array([np.array(emitters[j].sample_direction(
                it, mi.Point2f(0.5, 0.5), True)[0].p, float).ravel()[:3] for j in idx])
        lo[idx] = hi[idx] = pos
    finite_ok = np.isfinite(power) & (power > 0)
    kind[(kind == TREE) & ~finite_ok] = NONE
    kind[(kind == INFINITE) & ~finite_ok] = NONE
    return kind, lo, hi, w, cos_o, cos_e, two


class LightTreeSelection(LightSelection):
    """``light_selection=bvh``: infinite emitters outside the tree, the others chosen by
    traversing the light BVH at the shading point (module docstring)."""

    def __init__(self, scene):
        super().__init__(scene, "power")
        self.mode = "bvh"
        if self.count == 0:
            return
        power, first_n = self.power, self._first_normal
        kind, lo, hi, w, cos_o, cos_e, two = light_leaves(scene, self.emitters, power, first_n)
        if not np.any(kind != NONE):
            # every power estimate failed: all finite lights with power 1, like uniform
            fin = np.array([not mi.has_flag(e.flags(), mi.EmitterFlags.Infinite)
                            for e in self.emitters])
            kind = np.where(fin, TREE, INFINITE)
            power = np.ones(self.count)
        self.kind = kind
        tree_idx = np.nonzero(kind == TREE)[0]
        inf_idx = np.nonzero(kind == INFINITE)[0]
        self.n_tree, self.n_inf = len(tree_idx), len(inf_idx)
        # the infinite emitters as a group: their share of the power; inside the group by power
        total = power[tree_idx].sum() + power[inf_idx].sum()
        self.p_inf = float(power[inf_idx].sum() / total) if self.n_inf else 0.0
        if self.n_inf and not self.n_tree:
            self.p_inf = 1.0
        inf_share = power[inf_idx] / max(power[inf_idx].sum(), 1e-300)
        self.inf_pmf_np = self.p_inf * inf_share      # p(j) of every infinite emitter
        if self.n_inf:
            self.inf_distr = mi.DiscreteDistribution(inf_share.astype(np.float32))
        self.tree = None
        if self.n_tree:
            t = tree_idx
            self.tree_np = build(lo[t], hi[t], w[t], cos_o[t], cos_e[t], two[t], power[t])
            self.tree = DeviceTree(self.tree_np)
        # lookup tables: tree light -> emitter, infinite slot -> emitter, emitter -> slot
        slot = np.zeros(self.count, np.uint32)
        slot[tree_idx] = np.arange(self.n_tree)
        slot[inf_idx] = np.arange(self.n_inf)
        self.tree_index = tree_idx
        if is_jit():
            ids = np.array(dr.reinterpret_array(mi.UInt32, self.emitters_dr), dtype=np.int64)
            size = int(ids.max()) + 1
            kind_by_id = np.full(size, NONE, np.uint32)
            kind_by_id[ids] = kind
            slot_by_id = np.zeros(size, np.uint32)
            slot_by_id[ids] = slot
            self.kind_by_id, self.slot_by_id = mi.UInt32(kind_by_id), mi.UInt32(slot_by_id)
            self.tree_emitter = mi.UInt32(tree_idx.astype(np.uint32))
            self.inf_emitter = mi.UInt32(inf_idx.astype(np.uint32))
            self.inf_pmf = mi.Float(self.inf_pmf_np.astype(np.float32))
            dr.make_opaque(self.kind_by_id, self.slot_by_id, self.tree_emitter,
                           self.inf_emitter, self.inf_pmf)
        else:
            self.by_ptr = {e.ptr: (int(kind[j]), int(slot[j])) for j, e in enumerate(self.emitters)}
            self.tree_emitter, self.inf_emitter = tree_idx, inf_idx
            self.inf_pmf = self.inf_pmf_np

    def _measure_power(self, scene):
        power, self._first_normal = emitter_powers(scene, self.emitters, normals=True)
        return power

    # the interface of LightSelection (sample_direction and pdf_direction are inherited)
    def sample(self, sample1, active=True):
        raise NotImplementedError("bvh selection needs the shading point: use choose")

    def _emitter(self, idx, active):
        if is_jit():
            return dr.gather(mi.EmitterPtr, self.emitters_dr, idx, active)
        return self.emitters[int(idx)]

    def choose(self, si, sample1, active=True):
        """(EmitterPtr, p(j | si), None): an infinite emitter with probability p_inf, else the
        light the tree traversal at (si.p, si.n) reaches."""
        emitter, pmf, _ = self._choose(si, sample1, active, self._traverse)
        return emitter, pmf, None

    def _traverse(self, si, u, active):
        leaf, pmf_t, _ = self.tree.traverse(si.p, si.n, u, active)
        return leaf, pmf_t, None

    def _choose(self, si, sample1, active, tree_pick):
        """(EmitterPtr, p(j | si), what ``tree_pick`` returned besides the leaf and its pmf):
        an infinite emitter with probability p_inf, else the light ``tree_pick(si, u,
        active)`` -> (leaf, pmf, extra) picks in the tree (``extra`` None for an infinite
        emitter's lane or without a tree)."""
        if self.count == 0:
            return self._emitter(0, False) if is_jit() else None, mi.Float(0.0), None
        p_inf = self.p_inf
        u = mi.Float(sample1)
        if self.n_inf:
            use_inf = u < p_inf
            j = self.inf_distr.sample(dr.minimum(u / p_inf, ONE_MINUS_EPS), active & use_inf)
            u = dr.minimum((u - p_inf) / (1.0 - p_inf), ONE_MINUS_EPS) if p_inf < 1 else u
        else:
            use_inf, j = mi.Bool(False), mi.UInt32(0)
        if self.tree is not None:
            leaf, pmf_t, extra = tree_pick(si, u, active & ~use_inf)
        else:
            leaf, pmf_t, extra = mi.UInt32(0), mi.Float(0.0), None
        if is_jit():
            e_inf = dr.gather(mi.UInt32, self.inf_emitter, j, use_inf) if self.n_inf else j
            e_tree = (dr.gather(mi.UInt32, self.tree_emitter, leaf, ~use_inf)
                      if self.n_tree else leaf)
        else:
            e_inf = int(self.inf_emitter[j]) if self.n_inf else 0
            e_tree = int(self.tree_emitter[leaf]) if self.n_tree else 0
        idx = dr.select(use_inf, e_inf, e_tree)
        p_j = (dr.gather(mi.Float, self.inf_pmf, j, use_inf) if is_jit() else
               (float(self.inf_pmf[j]) if self.n_inf else 0.0)) if self.n_inf else 0.0
        pmf = dr.select(use_inf, p_j, (1.0 - p_inf) * pmf_t)
        pmf = dr.select(active, pmf, 0.0)
        ok = active & (pmf > 0)
        if not is_jit() and not ok:
            return None, 0.0, None
        if not is_jit() and use_inf:
            extra = None
        return self._emitter(idx, ok), pmf, extra

    def pmf_at(self, si, emitter, active=True, norm=None):
        """p(j | si) of ``emitter``: the root-to-leaf walk of its bit trail for a tree light,
        its share of p_inf for an infinite one, 0 for an emitter never chosen."""
        if self.count == 0:
            return mi.Float(0.0)
        if is_jit():
            ids = dr.reinterpret_array(mi.UInt32, emitter)
            active = active & (ids != 0)
            kind = dr.gather(mi.UInt32, self.kind_by_id, ids, active)
            slot = dr.gather(mi.UInt32, self.slot_by_id, ids, active)
        else:
            if emitter is None or not active:
                return 0.0
            kind, slot = self.by_ptr.get(emitter.ptr, (NONE, 0))
        if not self.n_inf:
            pmf = mi.Float(0.0)
        elif is_jit():
            is_inf = active & (kind == INFINITE)
            pmf = dr.select(is_inf, dr.gather(mi.Float, self.inf_pmf, slot, is_inf), 0.0)
        else:
            pmf = float(self.inf_pmf[slot]) if kind == INFINITE else 0.0
        if self.tree is not None:
            in_tree = active & (kind == TREE)
            if is_jit() or in_tree:
                pmf_t = self.tree.pmf(slot, si.p, si.n, in_tree)
                pmf = dr.select(in_tree, (1.0 - self.p_inf) * pmf_t, pmf)
        return dr.select(active, pmf, 0.0)


class ResampledTreeSelection(LightTreeSelection):
    r"""``light_selection=ris``: resampled importance sampling of the light (Talbot et al.
    2005; the first stage of ReSTIR, Bitterli et al. 2020) over candidates from the tree.

    At a shading point x, M = ``candidates`` (``light_candidates``, default 4) candidates
    X_1..X_M are drawn, each marginally distributed as a plain light sample (Cranley-Patterson
    rotations of one sample: u + k/M for the light, which also stratifies the candidates over
    the tree's order, and the light-point sample plus k times the R2 sequence's step); one of
    them, Y, is kept with probability w_k / sum w, w_k = p^(X_k) / p(X_k), read by a second
    uniform v (a streaming reservoir).  The target p^ is

    * with the BSDF at x (every integrator passes it): the **unshadowed contribution**
      luminance(f L_e) of the candidate's own light sample (its light by the selection pmf,
      the infinite emitters' share included, its point by the emitter's sampling), as in
      ReSTIR's first stage: w_k = luminance(f weight_e) / p(light_k), the solid-angle density
      cancelling; an emitter sample and a BSDF evaluation per candidate;
    * without it (:meth:`weighted_choice`): the leaf's importance bound at x (the tree's own
      estimate of the unshadowed contribution, with that one light's exact distance and
      orientation); the candidates are tree lights, infinite emitters are chosen outside the
      tree as with ``bvh``.

    The light sample on Y is then weighted by

        (1/M) sum_k w_k / p^(Y)     (in place of 1 / p(Y)),

    which for any (even dependent) candidates that are each distributed as p gives
    E[...] = (1/M) sum_k E[g(X_k) / p(X_k)] = sum g: unbiased wherever p^ > 0 where the
    integrand is not zero (every light the tree can pick has a positive leaf importance; a
    non-zero contribution has a positive luminance).  One shadow ray per light sample, M
    traversals.  With unshadowed contributions proportional to p^ the variance of the light
    choice falls about as 1/M (the relative variance of the unshadowed direct light on the
    1,024-light field, mean over 64 floor points: 0.57 with the tree alone, 0.29 / 0.15 / 0.07
    with 2 / 4 / 8 independent candidates and the bound as target, computed exactly from the
    tree's pmf; renders there: the relative per-pixel variance fell 4x with 4 candidates and
    the bound, 5x with the contribution).

    **MIS.**  The density of a resampled light sample has no closed form, so the MIS weights
    of light samples and of BSDF-sampled emission both use the selection's own density
    p(Y) p_Y(omega) (``ds.pdf``, :meth:`pmf_at`): the two weights still sum to one for every
    direction, which is all that unbiasedness needs (a weight is any partition of unity; the
    estimate each technique makes of its share is unbiased).

    The light choice reads a 2-D sample (``SAMPLE_DIMS``): (u, v)."""

    SAMPLE_DIMS = 2

    def __init__(self, scene, candidates: int = CANDIDATES):
        super().__init__(scene)
        self.mode = "ris"
        self.candidates = int(candidates)

    #: what the candidates are resampled by where the caller gives the BSDF: "contribution"
    #: (the unshadowed f L_e of each candidate's own light sample) or "bound" (the leaf
    #: importance, as without a BSDF)
    TARGET = "contribution"

    def sample_direction(self, si, sample1, sample2, active=True, bsdf=None, ctx=None):
        """A light sample resampled from ``candidates`` (the class docstring): ``ds.pdf`` is
        the selection's own density p(Y) p_Y(omega) (for MIS), ``weight`` the resampled
        L_e G / p.  With ``bsdf`` the target is the unshadowed contribution of each
        candidate's light sample, without it the leaf's importance bound."""
        if self.count == 0 or bsdf is None or self.TARGET != "contribution":
            return super().sample_direction(si, sample1, sample2, active)
        return self._resample_contribution(si, sample1, sample2, active, bsdf, ctx)

    @dr.syntax
    def _resample_contribution(self, si, sample1, sample2, active, bsdf, ctx):
        """M candidates X_k = (light, point): the light by the whole selection pmf p (the
        infinite emitters' share included) with u rotated by k/M, the point by the light's own
        sampling with ``sample2`` rotated by k times the R2 sequence's step; target p^ =
        luminance(f L_e), so w_k = luminance(f weight_e) / p(light) (the light's solid-angle
        density cancels).  The kept sample's weight is weight_e (1/M) sum w / p^."""
        m = self.candidates
        u, v = mi.Float(sample1[0]), mi.Float(sample1[1])
        s2 = mi.Point2f(sample2)
        active = mi.Bool(active)
        if is_jit():
            ds = dr.zeros(mi.DirectionSample3f, dr.width(si.p))
            weight = dr.zeros(mi.Spectrum, dr.width(si.p))
        else:   # dr.zeros cannot build a scalar one (its emitter pointer)
            ds, weight = mi.DirectionSample3f(), mi.Spectrum(0.0)
        w_sum, h_y, sel_y = mi.Float(0.0), mi.Float(0.0), mi.Float(0.0)
        k = mi.UInt32(0)
        while dr.hint(k < m, label="light selection: ris candidates",
                      exclude=[si, s2, u, active, bsdf, ctx]):
            emitter, sel, _ = self._choose(si, rotated(u, k, m), active, self._traverse)
            ok = active & (sel > 0)
            if dr.hint(is_jit() or ok, mode="scalar"):   # (scalar: a bool)
                ds_k, we_k = emitter.sample_direction(si, rotated_2d(s2, k), ok)
                ds_k.emitter = emitter
                f_k = bsdf.eval(ctx, si, si.to_local(ds_k.d), ok)
                h = dr.select(ok, dr.maximum(luminance(f_k * we_k), 0.0), 0.0)
                w = dr.select(h > 0, h / dr.select(h > 0, sel, 1.0), 0.0)
                take, w_sum, v = reservoir_step(w, w_sum, v)
                ds = dr.select(take, ds_k, ds)
                weight = dr.select(take, we_k, weight)
                h_y = dr.select(take, h, h_y)
                sel_y = dr.select(take, sel, sel_y)
            k += 1
        ok = active & (h_y > 0)
        ds.pdf = ds.pdf * sel_y
        weight = dr.select(ok, weight * (w_sum / (m * dr.select(ok, h_y, 1.0))), 0.0)
        return ds, weight, None

    def stratum(self, sample1, k, m):
        """Light sample k of m at a vertex: its candidates' uniform rotated by k / (m M), so the
        m M candidates of the m samples fall in distinct strata (by k/m, sample k would draw
        sample 0's candidate lights again when m = M), the reservoir's by k/m."""
        return mi.Point2f(rotated(sample1[0], k, m * self.candidates),
                          rotated(sample1[1], k, m))

    def choose(self, si, sample1, active=True):
        emitter, pmf, _, _ = self.weighted_choice(si, sample1, active)
        return emitter, pmf, None

    def weighted_choice(self, si, sample1, active=True):
        """(EmitterPtr, p(Y | si) of the tree (for MIS), None, the divisor of the light
        sample's weight): for a tree light (1 - p_inf) p^(Y) / ((1/M) sum w), for an infinite
        emitter p(Y) (as :meth:`LightSelection.weighted_choice`)."""
        v = sample1[1]

        def resampled(si, u, active):
            return self.tree.resample(si.p, si.n, u, v, self.candidates, active)

        emitter, sel, ratio = self._choose(si, sample1[0], active, resampled)
        if ratio is None:
            ratio = 1.0
        ok = active & (sel > 0)
        return emitter, sel, None, dr.select(ok, sel / dr.select(ok, ratio, 1.0), 0.0)
