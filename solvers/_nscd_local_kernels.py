"""Numba kernels of the NSCD solver (:mod:`solvers.nscd_`): the local solvers of the
Signorini-Coulomb law for one contact (the sweep is :mod:`solvers._nscd_kernels`).

One contact ``a`` with its Delassus block ``W`` (``m x m``, positive definite; read
entry by entry, so that a block that is not symmetric, as in a local problem whose
``W`` is not, is solved exactly too) and the rest ``r = (W p + b)_a - W p_a`` (what
the other contacts and the free motion give): find ``p`` with ``w = W p + r`` and De
Saxcé's ``ŵ = w + (mu |w_T|, 0)`` such that ``K ∋ p ⊥ ŵ ∈ K*``, ``K = {|p_T| <= mu
p_N}``. Its solutions are of three kinds:

- separation: ``p = 0``, valid iff ``r_N >= 0``;
- stick: ``w = 0``, ``p = -W^-1 r``, valid iff ``p`` is in ``K``;
- slide: ``p = p_N (1, -mu e)`` with ``|e| = 1``, ``p_N > 0``, ``w_N = 0`` and
  ``w_T = alpha e`` with ``alpha >= 0`` (the friction opposes the slip).

In 2D ``e = +-1``: both sliding branches are closed forms. In 3D ``w_N = 0`` gives
``p_N(e) = -r_N / (W_NN - mu W_NT e)`` and the slip direction ``e = (cos t, sin t)``
is a root of ``f(t) = e x w_T(e)`` with ``e . w_T(e) > 0`` and ``p_N > 0``:

1. Newton on the angle from the direction opposite to the stick trial's tangential
   impulse (already the root when ``W_TT`` is isotropic and ``W_NT = 0``, the case of
   two spheres or a sphere and a wall: no iteration);
2. if Newton does not end on a valid root: ``(W_NN - mu W_NT e) f`` is a
   trigonometric polynomial of degree 2 in the angle, so its zeros are the roots on
   the unit circle of a quartic in ``z = exp(i t)``; every one is polished by Newton
   and checked, and the valid one nearest the guess is taken (all solutions are seen:
   this makes the 3D sliding branch an exact enumeration, like 2D);
3. last resort (never needed in our random tests): a scan of the circle for sign
   changes of ``f``, refined by bisection.

The branches are tried in the order separation, stick, slide; the first valid one is
taken (the law may have several solutions for large ``mu``). Should none be valid to
rounding, the candidate with the smallest local natural map is taken.

Arrays are ``float64``; impulses are ``(nc, m)`` with the normal first, ``m`` in
{1, 2, 3}; ``H`` is given by its CSR arrays ``(indptr, indices, data)`` with the
``m`` rows of contact ``a`` at ``a m .. a m + m - 1``. Compiled on first use and
cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from solvers._contact_kernels import project_contact, project_coulomb_scalars

__all__ = [
    "SEPARATED",
    "SLIDE",
    "STICK",
    "fb_workspace",
    "local_2d",
    "local_solve",
    "local_solve_fb",
]

#: Branch codes returned by :func:`local_solve`.
SEPARATED = 0
STICK = 1
SLIDE = 2

_NEWTON_ITER = 30
_FB_ITER = 20
_FB_ACCEPT = 1e-12
_SCAN = 360
_BISECT = 200
_EPS = 2.220446049250313e-16


@njit(cache=True)
def local_solve(W, Winv, r, mu, out):
    """Exact solution ``out`` (length ``m``) of the Signorini-Coulomb law of one contact.

    ``W`` and ``Winv``: the ``m x m`` block and its inverse; ``r``: the rest, so that
    ``w = W out + r``. Returns the branch taken (SEPARATED, STICK, SLIDE).
    """
    m = r.shape[0]
    for k in range(m):
        out[k] = 0.0
    rn = r[0]
    if rn >= 0.0 or W[0, 0] <= 0.0:
        return SEPARATED
    if m == 1 or mu == 0.0:
        # Frictionless: p_T = 0 and w_N = 0.
        out[0] = -rn / W[0, 0]
        return SLIDE if m > 1 else STICK
    if m == 2:
        return _local_2d(W, Winv, r, mu, out)
    return _local_3d(W, Winv, r, mu, out)


@njit(cache=True)
def _local_2d(W, Winv, r, mu, out):
    pn, pt, branch = local_2d(
        W[0, 0], W[0, 1], W[1, 0], W[1, 1],
        Winv[0, 0], Winv[0, 1], Winv[1, 0], Winv[1, 1], r[0], r[1], mu,
    )  # fmt: skip
    if branch >= 0:
        out[0] = pn
        out[1] = pt
        return branch
    # Rounding at a branch boundary: the candidate with the smallest local residual.
    _best_candidate(W, r, mu, pn, pt, 0.0, out)
    if out[0] <= 0.0:
        return SEPARATED
    return STICK if abs(out[1]) < mu * out[0] else SLIDE


@njit(cache=True, inline="always")
def local_2d(w00, w01, w10, w11, i00, i01, i10, i11, rn, rt, mu):
    """The 2D law of one contact from the scalars of its block ``W``, of ``W^-1`` (``iNM``)
    and of its rest ``r``, with ``r_N < 0``, ``W_NN > 0`` and ``mu > 0``: ``(p_N, p_T,
    branch)``, every branch tried as in the module's docstring. Branch -1: none is valid
    to rounding, and ``(p_N, p_T)`` is the stick trial.

    Scalars rather than arrays so that a sweep (:func:`solvers._nscd_kernels.nscd_sweeps`)
    reads them in place, without a view of the block per contact.
    """
    pn = -(i00 * rn + i01 * rt)
    pt = -(i10 * rn + i11 * rt)
    if pn >= 0.0 and abs(pt) <= mu * pn:
        return pn, pt, STICK
    # Slip s = sign(w_T), p_T = -s mu p_N. The stick trial's p_T points against the
    # slip: try that branch first (both may hold for large mu with coupling).
    first = -1.0 if pt > 0.0 else 1.0
    for attempt in range(2):
        s = first if attempt == 0 else -first
        den = w00 - s * mu * w01
        if den <= 0.0:
            continue
        qn = -rn / den
        qt = -s * mu * qn
        wt = w10 * qn + w11 * qt + rt
        if s * wt >= 0.0:
            return qn, qt, SLIDE
    return pn, pt, -1


@njit(cache=True)
def _local_3d(W, Winv, r, mu, out):
    rn = r[0]
    pn = -(Winv[0, 0] * r[0] + Winv[0, 1] * r[1] + Winv[0, 2] * r[2])
    p1 = -(Winv[1, 0] * r[0] + Winv[1, 1] * r[1] + Winv[1, 2] * r[2])
    p2 = -(Winv[2, 0] * r[0] + Winv[2, 1] * r[1] + Winv[2, 2] * r[2])
    nt = np.sqrt(p1 * p1 + p2 * p2)
    if pn >= 0.0 and nt <= mu * pn:
        out[0] = pn
        out[1] = p1
        out[2] = p2
        return STICK
    # Slip direction guess: against the stick trial's tangential impulse.
    if nt > 0.0:
        theta0 = np.arctan2(-p2, -p1)
    else:
        theta0 = np.arctan2(r[2], r[1])
    ok, theta = _newton_angle(W, r, mu, theta0, True)
    if not ok:
        ok, theta = _polynomial_angle(W, r, mu, theta0)
    if not ok:
        ok, theta = _scan_angle(W, r, mu, theta0)
    if ok:
        ct, st = np.cos(theta), np.sin(theta)
        den = W[0, 0] - mu * (W[0, 1] * ct + W[0, 2] * st)
        qn = -rn / den
        out[0] = qn
        out[1] = -mu * qn * ct
        out[2] = -mu * qn * st
        return SLIDE
    _best_candidate(W, r, mu, pn, p1, p2, out)
    if out[0] <= 0.0:
        return SEPARATED
    return STICK if np.sqrt(out[1] ** 2 + out[2] ** 2) < mu * out[0] else SLIDE


@njit(cache=True)
def _polynomial_angle(W, r, mu, theta0):
    """Every slip angle at once: ``den(theta) f(theta)`` is a trigonometric polynomial of
    degree 2, i.e. ``z^-2 P(z)`` with ``z = exp(i theta)`` and ``P`` a quartic whose roots
    on the unit circle are the candidate angles. Each is polished by Newton on ``f``
    and checked; of the valid ones, the nearest ``theta0``."""
    rn, r1, r2 = r[0], r[1], r[2]
    # den f = A c^2 + B c s + C s^2 + D c + E s  (c = cos, s = sin)
    A = mu * (rn * W[2, 1] - W[0, 1] * r2)
    B = mu * (rn * (W[2, 2] - W[1, 1]) - (W[0, 2] * r2 - W[0, 1] * r1))
    C = mu * (W[0, 2] * r1 - rn * W[1, 2])
    D = W[0, 0] * r2 - rn * W[2, 0]
    E = rn * W[1, 0] - W[0, 0] * r1
    coef = np.empty(5, dtype=np.complex128)
    coef[0] = complex(0.25 * (A - C), -0.25 * B)
    coef[1] = complex(0.5 * D, -0.5 * E)
    coef[2] = complex(0.5 * (A + C), 0.0)
    coef[3] = complex(0.5 * D, 0.5 * E)
    coef[4] = complex(0.25 * (A - C), 0.25 * B)
    size = 0.0
    for k in range(5):
        size = max(size, abs(coef[k]))
    if size == 0.0:
        return False, theta0
    for k in range(5):
        if abs(coef[k]) <= 1e-14 * size:
            coef[k] = 0.0
    first = 0
    while first < 5 and coef[first] == 0.0:
        first += 1
    if first >= 4:
        return False, theta0
    roots = np.roots(coef[first:])
    best = theta0
    best_dist = np.inf
    found = False
    for z in roots:
        modulus = abs(z)
        # Double roots (tangencies) sit off the circle by about sqrt(eps).
        if abs(modulus - 1.0) > 1e-4:
            continue
        ok, theta = _newton_angle(W, r, mu, np.arctan2(z.imag, z.real), False)
        if not ok:
            continue
        dist = abs(np.arctan2(np.sin(theta - theta0), np.cos(theta - theta0)))
        if dist < best_dist:
            best, best_dist, found = theta, dist, True
    return found, best


@njit(cache=True)
def _slide_eval(W, r, mu, theta):
    """At slip angle ``theta``: ``(valid, f, df, g, scale)`` with ``f = e x w_T``,
    ``df = f'``, ``g = e . w_T`` and a velocity scale of ``w_T``'s terms."""
    ct, st = np.cos(theta), np.sin(theta)
    den = W[0, 0] - mu * (W[0, 1] * ct + W[0, 2] * st)
    if den <= 0.0:
        return False, 0.0, 0.0, 0.0, 0.0
    pn = -r[0] / den
    a1 = W[1, 0] - mu * (W[1, 1] * ct + W[1, 2] * st)
    a2 = W[2, 0] - mu * (W[2, 1] * ct + W[2, 2] * st)
    w1 = pn * a1 + r[1]
    w2 = pn * a2 + r[2]
    f = ct * w2 - st * w1
    g = ct * w1 + st * w2
    dden = -mu * (-W[0, 1] * st + W[0, 2] * ct)
    dpn = -pn * dden / den
    da1 = -mu * (-W[1, 1] * st + W[1, 2] * ct)
    da2 = -mu * (-W[2, 1] * st + W[2, 2] * ct)
    dw1 = dpn * a1 + pn * da1
    dw2 = dpn * a2 + pn * da2
    df = -g + ct * dw2 - st * dw1
    scale = abs(r[1]) + abs(r[2]) + pn * (abs(a1) + abs(a2))
    return pn > 0.0, f, df, g, scale


@njit(cache=True)
def _newton_angle(W, r, mu, theta0, clamp):
    """Newton on ``f(theta) = 0``; ``(True, theta)`` at a valid root (``g >= 0``).

    ``clamp`` limits steps to half a radian (a start far from any root)."""
    theta = theta0
    for _ in range(_NEWTON_ITER):
        valid, f, df, g, scale = _slide_eval(W, r, mu, theta)
        if not valid:
            return False, theta
        if abs(f) <= 4.0 * _EPS * scale:
            return g >= 0.0, theta
        if df == 0.0:
            return False, theta
        step = -f / df
        # A step beyond a quarter turn means Newton is far from its basin.
        if clamp and step > 0.5:
            step = 0.5
        elif clamp and step < -0.5:
            step = -0.5
        theta += step
        if abs(step) <= 4.0 * _EPS * (1.0 + abs(theta)):
            valid, f, df, g, scale = _slide_eval(W, r, mu, theta)
            return valid and g >= 0.0 and abs(f) <= 1e-10 * scale, theta
    return False, theta


@njit(cache=True)
def _scan_angle(W, r, mu, theta0):
    """Roots of ``f`` with ``g > 0`` on the circle by sign changes and bisection.

    Of several roots, the one nearest ``theta0``.
    """
    h = 2.0 * np.pi / _SCAN
    best = 0.0
    best_dist = np.inf
    found = False
    t_prev = theta0 - np.pi
    v_prev, f_prev, _, g_prev, _ = _slide_eval(W, r, mu, t_prev)
    for i in range(1, _SCAN + 1):
        t = theta0 - np.pi + i * h
        v, f, _, g, _ = _slide_eval(W, r, mu, t)
        if v and v_prev and (g > 0.0 or g_prev > 0.0) and (f == 0.0 or f * f_prev < 0.0):
            lo, hi, flo = t_prev, t, f_prev
            for _ in range(_BISECT):
                mid = 0.5 * (lo + hi)
                if mid <= lo or mid >= hi:
                    break
                _, fm, _, _, _ = _slide_eval(W, r, mu, mid)
                if fm == 0.0:
                    lo = hi = mid
                    break
                if (fm < 0.0) == (flo < 0.0):
                    lo, flo = mid, fm
                else:
                    hi = mid
            root = 0.5 * (lo + hi)
            vr, _, _, gr, _ = _slide_eval(W, r, mu, root)
            dist = abs(root - theta0)
            if vr and gr >= 0.0 and dist < best_dist:
                best, best_dist, found = root, dist, True
        t_prev, v_prev, f_prev, g_prev = t, v, f, g
    return found, best


@njit(cache=True)
def _best_candidate(W, r, mu, pn, p1, p2, out):
    """Of separation and the projected stick trial, the one of least local natural map."""
    m = r.shape[0]
    cand = np.zeros(m)
    cand[0] = pn
    cand[1] = p1
    if m == 3:
        cand[2] = p2
    project_contact(cand, mu)
    zero = np.zeros(m)
    if _local_residual(W, r, mu, cand) <= _local_residual(W, r, mu, zero):
        for k in range(m):
            out[k] = cand[k]
    else:
        for k in range(m):
            out[k] = 0.0


@njit(cache=True)
def _local_residual(W, r, mu, p):
    """``|p - P_K(p - rho ŵ)|`` for one contact, ``rho = m / trace(W)``.

    Written out in scalars for ``m`` in {1, 2, 3} (it runs at every Newton iteration of
    :func:`local_solve_fb`, so without temporary arrays).
    """
    m = r.shape[0]
    return _local_residual_at(W, r, mu, p[0], p[1] if m > 1 else 0.0, p[2] if m > 2 else 0.0)


@njit(cache=True, inline="always")
def _local_residual_at(W, r, mu, p0, p1, p2):
    """:func:`_local_residual` at the impulse ``(p0, p1, p2)`` (unused components 0)."""
    m = r.shape[0]
    w0 = r[0] + W[0, 0] * p0
    w1 = 0.0
    w2 = 0.0
    tr = W[0, 0]
    if m > 1:
        w0 += W[0, 1] * p1
        w1 = r[1] + W[1, 0] * p0 + W[1, 1] * p1
        tr += W[1, 1]
    if m > 2:
        w0 += W[0, 2] * p2
        w1 += W[1, 2] * p2
        w2 = r[2] + W[2, 0] * p0 + W[2, 1] * p1 + W[2, 2] * p2
        tr += W[2, 2]
    rho = m / tr
    w0 += mu * np.sqrt(w1 * w1 + w2 * w2)
    x0 = p0 - rho * w0
    x1 = p1 - rho * w1
    x2 = p2 - rho * w2
    if m == 1:
        x0 = max(x0, 0.0)
    else:
        x0, x1, x2 = project_coulomb_scalars(x0, x1, x2, mu)
    return np.sqrt((p0 - x0) ** 2 + (p1 - x1) ** 2 + (p2 - x2) ** 2)


# -- the hybrid local solver: Fischer-Burmeister Newton, exact fallback ---------------------
@njit(cache=True)
def fb_workspace(m):
    """Scratch for :func:`local_solve_fb` on contacts of ``m`` components."""
    return np.empty((6 + m, m))


@njit(cache=True)
def local_solve_fb(W, Winv, r, mu, start, out, work=None):
    """Newton on the modified Fischer-Burmeister function of one contact, from ``start``.

    With ``X = (mu p_N, p_T)`` and ``Y = (ŵ_N / mu, ŵ_T)`` (``ŵ`` De Saxcé's modified
    velocity) the law is the complementarity ``L ∋ X ⊥ Y ∈ L`` in the self-dual
    second-order cone ``L``, i.e. ``phi(p) = X + Y - (X∘X + Y∘Y)^(1/2) = 0`` in the
    Jordan algebra of ``L`` (Fukushima, Luo and Tseng 2002). Newton's direction uses a
    forward-difference Jacobian (``phi`` is semismooth, differentiable almost
    everywhere), with a backtracking line search on ``|phi|^2``. The answer is
    accepted when its local natural map is below ``_FB_ACCEPT`` times ``rho |r|``
    (``rho = m / trace(W)``), the bound the exact solver meets; otherwise the exact
    solver (:func:`local_solve`) answers.
    This is the hybrid strategy of Gauss-Seidel codes: a fast, warm-started Newton
    with an exact solve as its safety net. Returns True when Newton answered.

    ``work``: scratch of shape ``(6 + m, m)`` or larger (:func:`fb_workspace`), so that
    a sweep allocates it once rather than at every contact; None allocates it here.
    """
    m = r.shape[0]
    if m == 1 or mu == 0.0 or W[0, 0] <= 0.0:
        local_solve(W, Winv, r, mu, out)
        return True
    if work is None:
        return _fb_newton(W, Winv, r, mu, start, out, fb_workspace(m))
    return _fb_newton(W, Winv, r, mu, start, out, work)


# Rows of the workspace of _fb_newton: rows _J .. _J + m - 1 hold the Jacobian.
_P, _PHI, _TRIAL, _PHI_T, _RHS, _DP, _J = 0, 1, 2, 3, 4, 5, 6


@njit(cache=True)
def _fb_newton(W, Winv, r, mu, start, out, work):
    """:func:`local_solve_fb` for ``m`` in {2, 3}, ``mu > 0`` and ``W_NN > 0``, on the
    rows of ``work`` (indexed in place: no array is made per call)."""
    m = r.shape[0]
    # The size of the impulses at stake: rho |r|, rho = m / trace(W) (the step of the
    # local natural map).
    tr = 0.0
    nr = 0.0
    for k in range(m):
        tr += W[k, k]
        nr += r[k] * r[k]
    scale = m * np.sqrt(nr) / tr
    if scale == 0.0:
        for k in range(m):
            out[k] = 0.0
        return True
    for k in range(m):
        work[_P, k] = start[k]
    project_contact(work[_P, :m], mu)
    _fb_value(W, r, mu, work, _P, _PHI)
    merit = _sq(work, _PHI, m)
    for _ in range(_FB_ITER):
        if _residual_row(W, r, mu, work, _P, m) <= _FB_ACCEPT * scale:
            break
        h = np.sqrt(_EPS) * scale
        for ll in range(m):
            for k in range(m):
                work[_TRIAL, k] = work[_P, k]
            work[_TRIAL, ll] += h
            _fb_value(W, r, mu, work, _TRIAL, _PHI_T)
            for k in range(m):
                work[_J + k, ll] = (work[_PHI_T, k] - work[_PHI, k]) / h
        for k in range(m):
            work[_RHS, k] = -work[_PHI, k]
        if not _solve_small(work, m):
            break
        t = 1.0
        improved = False
        merit_t = merit
        for _ls in range(30):
            for k in range(m):
                work[_TRIAL, k] = work[_P, k] + t * work[_DP, k]
            _fb_value(W, r, mu, work, _TRIAL, _PHI_T)
            merit_t = _sq(work, _PHI_T, m)
            if merit_t <= (1.0 - 1e-4 * t) * merit:
                improved = True
                break
            t *= 0.5
        if not improved:
            break
        for k in range(m):
            work[_P, k] = work[_TRIAL, k]
            work[_PHI, k] = work[_PHI_T, k]
        merit = merit_t
    project_contact(work[_P, :m], mu)
    if _residual_row(W, r, mu, work, _P, m) <= _FB_ACCEPT * scale:
        for k in range(m):
            out[k] = work[_P, k]
        return True
    local_solve(W, Winv, r, mu, out)
    return False


@njit(cache=True, inline="always")
def _residual_row(W, r, mu, work, row, m):
    """:func:`_local_residual` at the impulse in row ``row`` of ``work``."""
    return _local_residual_at(W, r, mu, work[row, 0], work[row, 1], work[row, 2] if m > 2 else 0.0)


@njit(cache=True, inline="always")
def _sq(work, row, m):
    total = 0.0
    for k in range(m):
        total += work[row, k] * work[row, k]
    return total


@njit(cache=True, inline="always")
def _fb_value(W, r, mu, work, src, dst):
    """Row ``dst`` of ``work`` <- ``phi = X + Y - (X∘X + Y∘Y)^(1/2)`` for the impulse in
    row ``src`` (see :func:`local_solve_fb`).

    Written out for ``m`` in {2, 3}, without temporary arrays (it runs a few times per
    Newton iteration of every contact of every sweep).
    """
    m = r.shape[0]
    q0 = work[src, 0]
    q1 = work[src, 1]
    w0 = r[0] + W[0, 0] * q0 + W[0, 1] * q1
    w1 = r[1] + W[1, 0] * q0 + W[1, 1] * q1
    w2 = 0.0
    q2 = 0.0
    if m == 3:
        q2 = work[src, 2]
        w0 += W[0, 2] * q2
        w1 += W[1, 2] * q2
        w2 = r[2] + W[2, 0] * q0 + W[2, 1] * q1 + W[2, 2] * q2
    x0 = mu * q0
    y0 = (w0 + mu * np.sqrt(w1 * w1 + w2 * w2)) / mu
    # z = X∘X + Y∘Y = (|X|^2 + |Y|^2, 2 x0 x_T + 2 y0 y_T)
    z0 = x0 * x0 + y0 * y0 + q1 * q1 + w1 * w1 + q2 * q2 + w2 * w2
    z1 = 2.0 * (x0 * q1 + y0 * w1)
    z2 = 2.0 * (x0 * q2 + y0 * w2)
    nz = np.sqrt(z1 * z1 + z2 * z2)
    s1 = np.sqrt(max(z0 - nz, 0.0))
    s2 = np.sqrt(z0 + nz)
    # sqrt(z) = ((s1 + s2) / 2, (s2 - s1) / 2 zb / |zb|)
    half = 0.5 * (s2 - s1) / nz if nz > 0.0 else 0.0
    work[dst, 0] = x0 + y0 - 0.5 * (s1 + s2)
    work[dst, 1] = q1 + w1 - half * z1
    if m == 3:
        work[dst, 2] = q2 + w2 - half * z2


@njit(cache=True, inline="always")
def _solve_small(work, m):
    """Row ``_DP`` of ``work`` <- ``J^-1 rhs`` (``J`` in rows ``_J ..``, ``rhs`` in row
    ``_RHS``), ``m <= 3``, by Gaussian elimination with partial pivoting, in place on
    ``J`` and ``rhs``; False when ``J`` is singular to rounding."""
    big = 0.0
    for i in range(m):
        for j in range(m):
            big = max(big, abs(work[_J + i, j]))
    if big == 0.0:
        return False
    for c in range(m):
        piv = c
        for i in range(c + 1, m):
            if abs(work[_J + i, c]) > abs(work[_J + piv, c]):
                piv = i
        if abs(work[_J + piv, c]) <= 1e-14 * big:
            return False
        if piv != c:
            for j in range(m):
                work[_J + c, j], work[_J + piv, j] = work[_J + piv, j], work[_J + c, j]
            work[_RHS, c], work[_RHS, piv] = work[_RHS, piv], work[_RHS, c]
        for i in range(c + 1, m):
            f = work[_J + i, c] / work[_J + c, c]
            for j in range(c, m):
                work[_J + i, j] -= f * work[_J + c, j]
            work[_RHS, i] -= f * work[_RHS, c]
    for i in range(m - 1, -1, -1):
        s = work[_RHS, i]
        for j in range(i + 1, m):
            s -= work[_J + i, j] * work[_DP, j]
        work[_DP, i] = s / work[_J + i, i]
    return True
