"""The photometric model of one printed marker over its fitted pixels: ``perception.marker_fit``'s model.

Its parameters (the corners' shifts, the blur, the edge offset and the grid lines' offsets), the black coverage of
the marker's square less its white code cells, offset and blurred along each module axis, with the levels solved
linearly at each evaluation (variable projection) and Kaufman's projected Jacobian; the coverage and its Jacobian
are one compiled kernel (``_evaluate``). What the model is and why it is exact along the edges:
``perception.marker_fit``'s docstring. The fit (the pixels it takes, the solver, the checks) is there too.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from monodock.core.compiled import kernel

__all__: list[str] = []  # nothing public: perception.marker_fit is the model's one user

F64 = NDArray[np.float64]

SIGMA0_PX = 0.5  # the blur's start
SQRT1_2 = 1.0 / math.sqrt(2.0)
INV_SQRT2PI = 1.0 / math.sqrt(2.0 * math.pi)
Z_SATURATED = 8.5  # |z| beyond which the normal CDF is 0 or 1 to double precision (1e-17)
# Abramowitz & Stegun 7.1.26: erfc(x) = (a1 k + ... + a5 k^5) exp(-x^2), k = 1 / (1 + p x), x >= 0, to 1.5e-7
_AS_P = 0.3275911
_AS_A1, _AS_A2, _AS_A3, _AS_A4, _AS_A5 = 0.254829592, -0.284496736, 1.421413741, -1.453152027, 1.061405429


# --- the model -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Pixels:
    """The fitted pixels: normalised coordinates (N, 2), d(normalised)/d(pixel) (N, 2, 2), the white's slope
    basis (N, 2) and the grey levels (N,)."""

    xn: F64
    jn: F64
    dxy: F64
    obs: F64


@dataclass(frozen=True)
class _State:
    """The model at one parameter vector: cost (half the squared residual), rms, levels, and the projected
    normal matrix and gradient of the free parameters."""

    cost: float
    rms: float
    levels: F64
    normal: F64
    gradient: F64


class _Model:
    """The photometric model of one marker over its fixed pixels. Full parameters q: the corners' shifts (8,
    normalised times the focal lengths), blur, offset, then the grid lines' offsets in u and in v (M - 1 each)."""

    def __init__(self, pixels: _Pixels, start_n: F64, focal: F64, black: F64, offset_px: float | None) -> None:
        self.pixels = pixels
        self.start_n = start_n
        self.focal = focal
        self.focal_per_shift = np.tile(focal, 4)  # the shifts are normalised times the focal lengths
        M = black.shape[0]
        self.square = np.array([[0.0, 0.0], [M, 0.0], [M, M], [0.0, M]])
        self.grow, self.shrink = _white_patterns(black.tobytes(), M)
        self.q0 = np.zeros(10 + 2 * (M - 1))
        self.q0[8] = SIGMA0_PX
        if offset_px is None:
            self.free = np.arange(self.q0.size)
        else:
            self.q0[9] = offset_px
            self.free = np.delete(np.arange(self.q0.size), 9)
        # Each parameter's largest move in one step (px; the grid lines in modules): a Gauss-Newton step
        # beyond them is a line jumping to a neighbouring edge, which only costs rejected evaluations.
        self.max_step = np.r_[np.full(8, 0.5), 0.2, 0.2, np.full(2 * (M - 1), 0.1)][self.free]
        n = pixels.obs.size
        self._J, self._Jm, self._r = np.empty((n, self.q0.size)), np.empty((n, self.free.size)), np.empty(n)

    def corners_n(self, q: F64) -> F64:
        return np.asarray(self.start_n + q[:8].reshape(4, 2) / self.focal)

    def evaluate(self, q: F64) -> _State | None:
        """The model at q, or None where it cannot be evaluated (a degenerate quad, singular levels)."""
        px = self.pixels
        pattern = self.shrink if q[9] >= 0.0 else self.grow
        try:
            G, dg = _homography_and_jacobian(self.corners_n(q), self.square)
        except np.linalg.LinAlgError:
            return None
        ok, cost, levels, correction = _evaluate(
            q, self.free, G, dg / self.focal_per_shift, px.xn, px.jn, px.dxy, px.obs, pattern, self._J, self._Jm,
            self._r,
        )  # fmt: skip
        if not ok:
            return None
        normal = self._Jm.T @ self._Jm - correction
        return _State(cost, math.sqrt(2.0 * cost / px.obs.size), levels, normal, self._Jm.T @ self._r)


# --- geometry --------------------------------------------------------------------------------------


def _dlt(src: F64, dst: F64) -> tuple[F64, F64]:
    """The DLT system A h = b of the homography h (h33 = 1) with H src_k ~ dst_k for 4 point pairs."""
    x, y, u, v = src[:, 0], src[:, 1], dst[:, 0], dst[:, 1]
    A = np.zeros((8, 8))
    A[0::2, 0], A[0::2, 1], A[0::2, 2], A[0::2, 6], A[0::2, 7] = x, y, 1.0, -u * x, -u * y
    A[1::2, 3], A[1::2, 4], A[1::2, 5], A[1::2, 6], A[1::2, 7] = x, y, 1.0, -v * x, -v * y
    return A, np.asarray(dst, dtype=np.float64).ravel()


def _homography(src: F64, dst: F64) -> F64:
    """The 3x3 H (h33 = 1) with H src_k ~ dst_k for 4 point pairs; LinAlgError if three are in line."""
    A, b = _dlt(src, dst)
    return np.append(np.linalg.solve(A, b), 1.0).reshape(3, 3)


def _homography_and_jacobian(src: F64, dst: F64) -> tuple[F64, F64]:
    """``_homography`` and d(h0..h7)/d(src: x0 y0 x1 y1 ...), (8, 8): A h = b, so dh = -A^-1 (dA h)."""
    A, b = _dlt(src, dst)
    h = np.linalg.solve(A, b)
    u, v = dst[:, 0], dst[:, 1]
    dAh = np.zeros((8, 8))
    even, odd = np.arange(0, 8, 2), np.arange(1, 8, 2)
    dAh[even, even], dAh[odd, even] = h[0] - u * h[6], h[3] - v * h[6]
    dAh[even, odd], dAh[odd, odd] = h[1] - u * h[7], h[4] - v * h[7]
    return np.append(h, 1.0).reshape(3, 3), np.asarray(-np.linalg.solve(A, dAh), dtype=np.float64)


@functools.lru_cache(maxsize=64)
def _white_patterns(black_bytes: bytes, M: int) -> tuple[F64, F64]:
    """The refined grid's white code (R_grow, R_shrink), (2M+1, 2M+1), row v, column u: index 2l is the strip
    of grid line l, 2i+1 the core of cell i. Only the code counts: the border and the outside are not white
    here (the square accounts for them)."""
    black = np.frombuffer(black_bytes, dtype=np.float64).reshape(M, M)
    P = np.zeros((M + 2, M + 2))
    P[1:-1, 1:-1] = 1.0 - black
    P[1, :] = P[-2, :] = P[:, 1] = P[:, -2] = 0.0  # the border ring is black by definition
    # The padded cells each refined index touches: a core (odd) one cell, a strip (even) the two beside it.
    index = np.arange(2 * M + 1)
    lo, hi = index // 2 + index % 2, index // 2 + 1
    corners = np.stack([P[np.ix_(a, b)] for a in (lo, hi) for b in (lo, hi)])
    grow, shrink = corners.max(axis=0), corners.min(axis=0)
    grow.flags.writeable = shrink.flags.writeable = False
    return grow, shrink


# --- kernels ---------------------------------------------------------------------------------------


@kernel
def _solve_in_place(A: F64, B: F64) -> bool:  # noqa: PLR0912 # pragma: no cover - compiled
    """A X = B for a small square A, by Gaussian elimination with partial pivoting; X into B, A destroyed.
    False if A is singular to working precision. (np.linalg in a kernel needs scipy's LAPACK bindings, and the
    robot side must not depend on scipy.)"""
    n, m = A.shape[0], B.shape[1]
    scale = 0.0
    for i in range(n):
        for j in range(n):
            scale = max(scale, abs(A[i, j]))
    for c in range(n):
        p, best = c, abs(A[c, c])
        for r in range(c + 1, n):
            if abs(A[r, c]) > best:
                p, best = r, abs(A[r, c])
        if not best > 1e-13 * scale:
            return False
        if p != c:
            for k in range(n):
                A[c, k], A[p, k] = A[p, k], A[c, k]
            for k in range(m):
                B[c, k], B[p, k] = B[p, k], B[c, k]
        for r in range(c + 1, n):
            f = A[r, c] / A[c, c]
            if f != 0.0:
                for k in range(c, n):
                    A[r, k] -= f * A[c, k]
                for k in range(m):
                    B[r, k] -= f * B[c, k]
    for c in range(n - 1, -1, -1):
        for k in range(m):
            total = B[c, k]
            for j in range(c + 1, n):
                total -= A[c, j] * B[j, k]
            B[c, k] = total / A[c, c]
    return True


@kernel
def _normal(z: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """The standard normal's CDF and density at z. The CDF by Abramowitz & Stegun 7.1.26 (to 1e-7: a
    hundred-thousandth of a grey level on these edges), which shares the density's exponential: a third of
    the cost of math.erfc and math.exp, and these run a few times per pixel and evaluation."""
    if z > Z_SATURATED:
        return 1.0, 0.0
    if z < -Z_SATURATED:
        return 0.0, 0.0
    e = math.exp(-0.5 * z * z)
    x = abs(z) * SQRT1_2
    k = 1.0 / (1.0 + _AS_P * x)
    tail = 0.5 * k * (_AS_A1 + k * (_AS_A2 + k * (_AS_A3 + k * (_AS_A4 + k * _AS_A5)))) * e
    return (1.0 - tail if z >= 0.0 else tail), INV_SQRT2PI * e


@kernel
def _square_axis(
    t: float, g: float, s: float, delta: float, M: int
) -> tuple[float, float, float, float]:  # pragma: no cover
    """One axis of the dilated square [-d, M + d] blurred: F and dF/dt, dF/ds, dF/ddelta."""
    st = s * g
    z1, z2 = (t + delta * g) / st, (t - M - delta * g) / st
    P1, p1 = _normal(z1)
    P2, p2 = _normal(z2)
    return P1 - P2, (p1 - p2) / st, -(p1 * z1 - p2 * z2) / s, (p1 + p2) / s


@kernel
def _white_axis(
    t: float, g: float, s: float, delta: float, off: F64, reach: float, A: F64, A_t: F64, A_s: F64, A_d: F64,
    P_t: F64,
) -> tuple[int, int, int, int]:  # pragma: no cover - compiled  # fmt: skip
    """One axis of the refined cells, blurred: A (2M+1,) and dA/dt, dA/ds, dA/ddelta, and dP/dt (2M+2,) at
    the breakpoints l + off_l -+ |delta| g (for the grid lines' derivatives).

    Only the lines within ``reach`` (modules: the largest offset plus Z_SATURATED blurs, before the dilation)
    of t are evaluated: the others' breakpoints are 0 or 1 to double precision. Returns the window of refined
    cells where A or a derivative is not 0 (first, last; empty if first > last), outside which A and its
    derivatives are 0 but not written, and the lines evaluated (first, last), outside which P_t is not written.
    """
    M = off.shape[0] - 1
    inv_st = 1.0 / (s * g)
    inv_s = 1.0 / s
    d = abs(delta) * g
    dd = g if delta >= 0.0 else -g  # d(breakpoint l -+ d)/d(delta) = -+ sign(delta) g
    reach_t = reach + d + Z_SATURATED * s * g
    l0, l1 = max(math.ceil(t - reach_t), 0), min(math.floor(t + reach_t), M)
    # the breakpoints of the lines before l0 are all 1: t is beyond them
    P_prev = 1.0 if l0 > 0 else 0.0
    pt_prev = ps_prev = pd_prev = 0.0
    first, last = A.shape[0], -1
    for line in range(l0, l1 + 1):
        centre = line + off[line]
        for side in range(2):
            k = 2 * line + side
            z = (t - (centre + d if side else centre - d)) * inv_st
            P, p = _normal(z)
            pt = p * inv_st
            ps = -p * z * inv_s
            pd = -pt * dd if side else pt * dd
            P_t[k] = pt
            if k > 0:
                A[k - 1], A_t[k - 1], A_s[k - 1], A_d[k - 1] = P_prev - P, pt_prev - pt, ps_prev - ps, pd_prev - pd
                if P_prev != P or pt != 0.0 or pt_prev != 0.0:
                    first = min(first, k - 1)
                    last = k - 1
            P_prev, pt_prev, ps_prev, pd_prev = P, pt, ps, pd
    k = 2 * (l1 + 1)  # the next breakpoint, 0 like all after it
    if 0 < k <= 2 * M and (P_prev != 0.0 or pt_prev != 0.0):
        A[k - 1], A_t[k - 1], A_s[k - 1], A_d[k - 1] = P_prev, pt_prev, ps_prev, pd_prev
        first = min(first, k - 1)
        last = k - 1
    return first, last, l0, l1


@kernel
def _evaluate(  # noqa: PLR0912, PLR0915
    q: F64, free: NDArray[np.intp], G: F64, dg: F64, xn: F64, jn: F64, dxy: F64, obs: F64, R: F64, J: F64,
    Jm: F64, r: F64,
) -> tuple[bool, float, F64, F64]:  # pragma: no cover - compiled  # fmt: skip
    """The model at the full parameters q, given the corners' homography G (normalised -> modules) and its
    derivatives dg (8, 8) with respect to the corners' shifts q[:8]: whether it could be evaluated, the cost
    (half the squared residual), the levels (w0, w1, w2, D) and Kaufman's correction of the normal matrix
    (F, F); into the scratch arrays: dC/dq (N, Q) into J, the residual into r (N,) and the model's derivatives
    with respect to the free parameters ``free`` (F,) at the current levels into Jm (N, F).

    The variable-projection problem's normal matrix is then Jm^T Jm - correction, its gradient Jm^T r (r is
    orthogonal to the levels' basis). q: the corners' shifts (8), blur, offset, the grid lines in u (M - 1),
    in v (M - 1); R: the refined white pattern for the offset's sign.
    """
    n = xn.shape[0]
    M = (q.shape[0] - 8) // 2
    nr = 2 * M + 1
    nf = free.shape[0]
    s, delta = q[8], q[9]
    off_u, off_v = np.zeros(M + 1), np.zeros(M + 1)
    reach_u = reach_v = 0.0
    for line in range(1, M):
        off_u[line], off_v[line] = q[9 + line], q[8 + M + line]
        reach_u, reach_v = max(reach_u, abs(off_u[line])), max(reach_v, abs(off_v[line]))
    levels = np.zeros(4)
    correction = np.zeros((nf, nf))
    A, A_t, A_s, A_d = np.empty(nr), np.empty(nr), np.empty(nr), np.empty(nr)
    B, B_t, B_s, B_d = np.empty(nr), np.empty(nr), np.empty(nr), np.empty(nr)
    PA_t, PB_t = np.empty(nr + 1), np.empty(nr + 1)
    AR, BR = np.empty(nr), np.empty(nr)
    gram, rhs = np.zeros((4, 4)), np.zeros((4, 1))
    for i in range(n):
        x, y = xn[i, 0], xn[i, 1]
        w = G[2, 0] * x + G[2, 1] * y + 1.0
        iw = 1.0 / w
        u = (G[0, 0] * x + G[0, 1] * y + G[0, 2]) * iw
        v = (G[1, 0] * x + G[1, 1] * y + G[1, 2]) * iw
        j00, j01 = (G[0, 0] - u * G[2, 0]) * iw, (G[0, 1] - u * G[2, 1]) * iw
        j10, j11 = (G[1, 0] - v * G[2, 0]) * iw, (G[1, 1] - v * G[2, 1]) * iw
        # |grad u|, |grad v| in pixels: the blur's scale along each module axis
        gu = math.hypot(j00 * jn[i, 0, 0] + j01 * jn[i, 1, 0], j00 * jn[i, 0, 1] + j01 * jn[i, 1, 1])
        gv = math.hypot(j10 * jn[i, 0, 0] + j11 * jn[i, 1, 0], j10 * jn[i, 0, 1] + j11 * jn[i, 1, 1])
        Fu, Fu_t, Fu_s, Fu_d = _square_axis(u, gu, s, delta, M)
        Fv, Fv_t, Fv_s, Fv_d = _square_axis(v, gv, s, delta, M)
        a0, a1, la0, la1 = _white_axis(u, gu, s, delta, off_u, reach_u, A, A_t, A_s, A_d, PA_t)
        b0, b1, lb0, lb1 = _white_axis(v, gv, s, delta, off_v, reach_v, B, B_t, B_s, B_d, PB_t)
        # AR = R A, BR = B^T R, where they are used: within a cell of the other axis' window (the grid lines'
        # derivatives reach a cell beyond it); elsewhere 0, so that a 0 derivative times them stays 0.
        for k in range(nr):
            AR[k] = 0.0
            BR[k] = 0.0
        for m in range(max(b0 - 1, 0), min(b1 + 3, nr)):
            total = 0.0
            for k in range(a0, a1 + 1):
                total += R[m, k] * A[k]
            AR[m] = total
        for m in range(max(a0 - 1, 0), min(a1 + 3, nr)):
            total = 0.0
            for k in range(b0, b1 + 1):
                total += B[k] * R[k, m]
            BR[m] = total
        white = white_t = white_s = white_d = white_v = 0.0
        for k in range(a0, a1 + 1):
            white += A[k] * BR[k]
            white_t += A_t[k] * BR[k]
            white_s += A_s[k] * BR[k]
            white_d += A_d[k] * BR[k]
        for k in range(b0, b1 + 1):
            white_v += B_t[k] * AR[k]
            white_s += B_s[k] * AR[k]
            white_d += B_d[k] * AR[k]
        c = Fu * Fv - white
        Cu = (Fu_t * Fv - white_t) * iw
        Cv = (Fu * Fv_t - white_v) * iw
        # dC/dcorner_k through the homography: du/dg = (x, y, 1, 0, 0, 0, -u x, -u y) / w, dv/dg likewise.
        for k in range(8):
            ga = x * dg[0, k] + y * dg[1, k] + dg[2, k]
            gb = x * dg[3, k] + y * dg[4, k] + dg[5, k]
            gc = x * dg[6, k] + y * dg[7, k]
            J[i, k] = Cu * (ga - u * gc) + Cv * (gb - v * gc)
        J[i, 8] = Fu_s * Fv + Fu * Fv_s - white_s
        J[i, 9] = Fu_d * Fv + Fu * Fv_d - white_d
        # Moving line l moves its two breakpoints 2l, 2l+1, which changes only refined cells 2l-1 .. 2l+1.
        for line in range(1, M):
            e0, e1 = 2 * line, 2 * line + 1
            J[i, 9 + line] = (
                PA_t[e0] * (BR[e0] - BR[e0 - 1]) + PA_t[e1] * (BR[e1] - BR[e0]) if la0 <= line <= la1 else 0.0
            )
            J[i, 8 + M + line] = (
                PB_t[e0] * (AR[e0] - AR[e0 - 1]) + PB_t[e1] * (AR[e1] - AR[e0]) if lb0 <= line <= lb1 else 0.0
            )
        # The levels' basis: white (1 - C), its slopes, black C.
        r[i] = c
        basis = (1.0 - c, (1.0 - c) * dxy[i, 0], (1.0 - c) * dxy[i, 1], c)
        for a_ in range(4):
            rhs[a_, 0] += basis[a_] * obs[i]
            for b_ in range(4):
                gram[a_, b_] += basis[a_] * basis[b_]
    gram_inv = np.eye(4)
    work = gram.copy()
    if not _solve_in_place(work, gram_inv):
        return False, np.inf, levels, correction
    for a_ in range(4):
        for b_ in range(4):
            levels[a_] += gram_inv[a_, b_] * rhs[b_, 0]
    w0, w1, w2, black = levels[0], levels[1], levels[2], levels[3]
    cost = 0.0
    AtJ = np.zeros((4, nf))
    for i in range(n):
        c = r[i]
        white_level = w0 + w1 * dxy[i, 0] + w2 * dxy[i, 1]
        res = obs[i] - (white_level * (1.0 - c) + black * c)
        r[i] = res
        cost += 0.5 * res * res
        # Kaufman's variable projection: the model's derivatives at the current levels; their part in the
        # levels' span comes off through the correction below, so the solver need not carry the levels.
        dm = black - white_level
        b0, b1, b2, b3 = 1.0 - c, (1.0 - c) * dxy[i, 0], (1.0 - c) * dxy[i, 1], c
        for f in range(nf):
            val = J[i, free[f]] * dm
            Jm[i, f] = val
            AtJ[0, f] += b0 * val
            AtJ[1, f] += b1 * val
            AtJ[2, f] += b2 * val
            AtJ[3, f] += b3 * val
    # correction = AtJ^T gram^-1 AtJ
    P = np.zeros((4, nf))
    for a_ in range(4):
        for f in range(nf):
            total = 0.0
            for b_ in range(4):
                total += gram_inv[a_, b_] * AtJ[b_, f]
            P[a_, f] = total
    for f in range(nf):
        for e in range(f, nf):
            total = 0.0
            for a_ in range(4):
                total += AtJ[a_, f] * P[a_, e]
            correction[f, e] = correction[e, f] = total
    return bool(np.isfinite(cost)), cost, levels, correction
