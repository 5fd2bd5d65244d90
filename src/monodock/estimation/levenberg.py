"""Levenberg–Marquardt for the planar fit: one loop for its models, their damped steps and covariances.

A model (``estimation.planar``) is how it evaluates a pose: the design [J | r] per corner, the normal matrix
N = [J | r]ᵀW[J | r] with H = JᵀWJ and g = JᵀWr (priors included) and the cost; and how many parameters it has,
which picks its linear algebra: the damped step and the marginal covariance of (x, y, yaw). ``levenberg_marquardt``
does the rest for every model: the damping schedule, the acceptance test, the convergence test and the covariances.

The (x, y, yaw) model evaluates in compiled code, so its fits run the loop compiled (``compiled_levenberg_marquardt``,
with ``step3`` and ``inverse3``). The (x, y, yaw, δ) model, δ a turn of the camera, projects through OpenCV, which
compiled code cannot call, so its fits run the same loop as Python (with ``step4`` and ``marginal4``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from monodock.core.compiled import inlined, kernel

__all__ = [
    "CHI2_TOLERANCE",
    "compiled_levenberg_marquardt",
    "inverse3",
    "levenberg_marquardt",
    "marginal3",
    "marginal4",
    "solve3_into",
    "step3",
    "step4",
]

# Converged when the next step would lower the cost (χ²) by less than this: a step of 1e-3 standard deviations.
CHI2_TOLERANCE = 1e-6


def levenberg_marquardt(
    problem: tuple[Any, ...],
    theta: Any,
    prior_information: Any,
    max_iterations: int,
    tolerance: float,
    evaluate: Any,
    step: Any,
    marginal: Any,
) -> tuple[Any, bool, float, Any, Any, float, Any, int, bool]:
    """Levenberg–Marquardt over k parameters from ``theta``, one evaluation (a projection with Jacobian) per iteration.

    Stops when the next step is below a thousandth of the estimate's standard deviation (δᵀHδ < ``CHI2_TOLERANCE``)
    or below ``tolerance`` in every parameter, or when ``max_iterations`` evaluations are spent.

    Args:
        problem: the model's fixed inputs, as its ``evaluate`` reads them; the third is the corner pixels (N, 2).
        theta: the start, shape (k,); the first three are x, y and yaw.
        prior_information: Λ (k, k), the information of the priors ``evaluate`` adds, for the covariances.
        max_iterations: cap on evaluations.
        tolerance: absolute step size below which the fit has converged in any case.
        evaluate: ``evaluate(th, problem, X, N, H, g) -> (ok, cost)``: fills the design X = [J | r] (N, 2, k + 1),
            r the pixel residuals, N = XᵀWX, H = JᵀWJ + Λ and g = JᵀWr + the priors' gradient at ``th``, and
            returns the cost (χ² plus the priors' terms); ok False when a corner is not in front of the camera
            or the cost is not finite.
        step: ``step(damped, H, g, lam, out) -> (solved, decrease)``: the damped step δ (damped·δ = −g) into
            ``out`` and δᵀHδ, the cost it would remove; solved False when ``damped`` is singular.
        marginal: ``marginal(information, factor)``: the (x, y, yaw) block of factor · information⁻¹.

    Returns:
        The parameters; whether any pose could be evaluated; and, from the last accepted evaluation, the cost, the
        covariance (F + Λ)⁻¹ and the residual-scaled one s²(F + s²Λ)⁻¹ of (x, y, yaw) (F the Fisher information at
        unit corner sigma, s the noise scale √(χ²/(2N − k))), s and the design X; then the evaluations and whether
        it converged.
    """
    n = problem[2].shape[0]
    k = theta.shape[0]
    X, Xt = np.empty((n, 2, k + 1)), np.empty((n, 2, k + 1))
    N, Nt = np.empty((k + 1, k + 1)), np.empty((k + 1, k + 1))
    H, Ht = np.empty((k, k)), np.empty((k, k))
    g, gt = np.empty(k), np.empty(k)
    th = theta.copy()
    ok, cost = evaluate(th, problem, X, N, H, g)
    iterations, converged, lam = 1, False, 1e-4
    damped, delta, trial = np.empty((k, k)), np.empty(k), np.empty(k)
    while ok and iterations < max_iterations:
        damped[:] = H
        for j in range(k):
            damped[j, j] *= 1.0 + lam
        solved, decrease = step(damped, H, g, lam, delta)
        if not solved:
            break
        # The step's size in standard deviations of the estimate (δᵀHδ, the cost it would remove): once
        # it is a thousandth of one, further steps change nothing that the noise lets anyone measure.
        # With noise, Gauss–Newton converges linearly (rate ~ residual size), so this saves iterations.
        largest = abs(delta[0])
        for j in range(1, k):
            largest = max(largest, abs(delta[j]))
        if decrease < CHI2_TOLERANCE or largest < tolerance:
            th += delta
            converged = True
            break
        trial[:] = th + delta
        ok_t, cost_t = evaluate(trial, problem, Xt, Nt, Ht, gt)
        iterations += 1
        if ok_t and cost_t <= cost:
            th[:], X[:], N[:], H[:], g[:], cost = trial, Xt, Nt, Ht, gt, cost_t
            lam = max(lam * 0.1, 1e-12)
        else:
            lam *= 10.0
            if lam > 1e12:
                break
    if not ok:
        return th, ok, np.inf, N, N, np.nan, X, iterations, False
    n_dof = 2 * n - k
    scale = math.sqrt(N[k, k] / n_dof) if n_dof > 0 else math.nan
    cov = marginal(N[:k, :k] + prior_information, 1.0)
    # (F/s² + Λ)⁻¹ written as s²(F + s²Λ)⁻¹, which stays finite for exact corners (s = 0).
    cov_res = marginal(N[:k, :k] + scale * scale * prior_information, scale * scale)
    return th, ok, cost, cov, cov_res, scale, X, iterations, converged


# The loop compiled, for a model whose evaluate, step and marginal are compiled too. Inlined into the kernel that
# calls it, so the model's functions are that kernel's constants: passed to a separate compiled function they are
# addresses of Python objects, and numba cannot cache a kernel that holds those.
compiled_levenberg_marquardt = inlined(levenberg_marquardt)


# --- three parameters (compiled) ------------------------------------------------------------------------


@kernel
def step3(
    damped: Any,
    H: Any,
    g: Any,
    lam: float,  # noqa: ARG001 - one signature for both sizes: step4's decrease uses it
    out: Any,
) -> tuple[bool, float]:  # pragma: no cover - compiled
    """``levenberg_marquardt``'s step for three parameters: δ by cofactors and δᵀHδ from H."""
    if not solve3_into(damped, -g, out):
        return False, 0.0
    decrease = 0.0
    for k in range(3):
        decrease += out[k] * (H[k, 0] * out[0] + H[k, 1] * out[1] + H[k, 2] * out[2])
    return True, decrease


@kernel
def solve3_into(A: Any, b: Any, out: Any) -> bool:  # pragma: no cover - compiled
    """out = x with A x = b for a 3x3 system, by cofactors; False when A is singular."""
    a, b_, c = A[0, 0], A[0, 1], A[0, 2]
    d, e, f = A[1, 0], A[1, 1], A[1, 2]
    g, h, i = A[2, 0], A[2, 1], A[2, 2]
    c0, c1, c2 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * c0 + b_ * c1 + c * c2
    if det == 0.0 or not np.isfinite(det):
        return False
    r0, r1, r2 = b[0], b[1], b[2]
    out[0] = (r0 * c0 + r1 * (c * h - b_ * i) + r2 * (b_ * f - c * e)) / det
    out[1] = (r0 * c1 + r1 * (a * i - c * g) + r2 * (c * d - a * f)) / det
    out[2] = (r0 * c2 + r1 * (b_ * g - a * h) + r2 * (a * e - b_ * d)) / det
    return True


@kernel
def inverse3(m: NDArray[np.float64], factor: float) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """factor · m⁻¹ for a 3x3 information matrix; infinite where it is singular (the pose is unobservable)."""
    out = np.empty((3, 3))
    a, b, c = m[0, 0], m[0, 1], m[0, 2]
    d, e, f = m[1, 0], m[1, 1], m[1, 2]
    g, h, i = m[2, 0], m[2, 1], m[2, 2]
    c0, c1, c2 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * c0 + b * c1 + c * c2
    if det == 0.0 or not np.isfinite(det) or not np.isfinite(factor):
        out[:] = np.inf if np.isfinite(factor) else np.nan
        return out
    k = factor / det
    out[0, 0], out[0, 1], out[0, 2] = c0 * k, (c * h - b * i) * k, (b * f - c * e) * k
    out[1, 0], out[1, 1], out[1, 2] = c1 * k, (a * i - c * g) * k, (c * d - a * f) * k
    out[2, 0], out[2, 1], out[2, 2] = c2 * k, (b * g - a * h) * k, (a * e - b * d) * k
    return out


# --- four parameters: (x, y, yaw) and a nuisance δ (Python) ----------------------------------------------


def step4(
    damped: NDArray[np.float64], H: NDArray[np.float64], g: NDArray[np.float64], lam: float, out: NDArray[np.float64]
) -> tuple[bool, float]:
    """``levenberg_marquardt``'s step for four parameters: δ by the Schur complement on the fourth, and δᵀHδ."""
    grad = g.tolist()
    s = _solve4x4(damped.tolist(), grad)
    if s is None:
        return False, 0.0
    h = H.diagonal().tolist()
    # δᵀHδ = −δᵀg − λ Σ H_kk δ_k² for the damped step: no second product needed.
    decrease = -(s[0] * grad[0] + s[1] * grad[1] + s[2] * grad[2] + s[3] * grad[3]) - lam * (
        h[0] * s[0] ** 2 + h[1] * s[1] ** 2 + h[2] * s[2] ** 2 + h[3] * s[3] ** 2
    )
    out[:] = s
    return True, decrease


def marginal4(information: NDArray[np.float64], factor: float) -> NDArray[np.float64]:
    """``marginal3`` of a 4x4 array, for ``levenberg_marquardt``."""
    return marginal3(information.tolist(), factor)


def marginal3(information: Sequence[Sequence[float]], factor: float) -> NDArray[np.float64]:
    """The (x, y, yaw) block of factor · information⁻¹ for a 4x4 information; infinite where it is singular."""
    reduced = _schur(information)
    if reduced is None:
        return np.full((3, 3), np.inf if math.isfinite(factor) else np.nan)
    return inverse3(np.array(reduced[0]), factor)


def _schur(H: Sequence[Sequence[float]]) -> tuple[list[list[float]], list[float], float] | None:
    """δ eliminated from a 4x4 information matrix: (A − b bᵀ/d, b, d) with H = [[A, b], [bᵀ, d]]; None if d ≤ 0.

    A − b bᵀ/d is the information of (x, y, yaw) with δ marginalised, so its inverse is their covariance.
    """
    d = H[3][3]
    if not d > 0.0 or not math.isfinite(d):
        return None
    b = [H[0][3], H[1][3], H[2][3]]
    return [[H[k][m] - b[k] * b[m] / d for m in range(3)] for k in range(3)], b, d


def _solve4x4(H: Sequence[Sequence[float]], g: Sequence[float]) -> list[float] | None:
    """The step x with H x = −g for the 4x4 (x, y, yaw, δ) system, by the Schur complement on δ."""
    reduced = _schur(H)
    if reduced is None:
        return None
    A, b, d = reduced
    s = _solve3(A, [-g[k] + b[k] * g[3] / d for k in range(3)])
    if s is None:
        return None
    return [s[0], s[1], s[2], (-g[3] - b[0] * s[0] - b[1] * s[1] - b[2] * s[2]) / d]


def _solve3(A: list[list[float]], b: list[float]) -> tuple[float, float, float] | None:
    """x with A x = b for a 3x3 system (``solve3_into``), None when A is singular."""
    out = np.empty(3)
    if not solve3_into(np.array(A, dtype=np.float64), np.array(b, dtype=np.float64), out):
        return None
    x0, x1, x2 = out.tolist()
    return x0, x1, x2
