"""One bundle adjustment of N cameras and the board poses that connect them.

The model is OpenCV's (pinhole, k1 k2 p1 p2 k3), written out in NumPy so that every observation
of every camera is projected in one vectorised pass: a board point X_b of view v is taken into
the world by the board pose (R_v, t_v), into camera c by its pose (R_c, t_c), and through the
camera's intrinsics. The world frame is the reference camera's (its pose is held at the
identity); the scale is the board's square. :func:`adjust` minimises the reprojection errors of
all corners over the free parameters with ``scipy.optimize.least_squares`` (trust region
reflective, a robust loss). The Jacobian's structure is used to build it: no residual depends
on two cameras or two views, so one parameter slot of every camera (or every view) is moved at
once, and a central-difference Jacobian costs 42 projections of all corners whatever the number
of cameras and views (:meth:`Problem.jacobian`). :func:`covariance` gives
each camera's standard deviations from the Jacobian at the solution, the board poses eliminated.
See docs/decisions/0030-n-camera-calibration.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

DIST_NAMES = ("k1", "k2", "p1", "p2", "k3")
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy")
EXTRINSIC_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")
LOSS = "cauchy"  # SciPy's robust loss: redescending, so a wrong view stops pulling (0030)
F_SCALE_PX = 4.0  # residual (px) from which a corner counts as a wrong one rather than noise


def rodrigues(rvecs: np.ndarray) -> np.ndarray:
    """Rotation matrices (n × 3 × 3) of rotation vectors (n × 3)."""
    rvecs = np.asarray(rvecs, float).reshape(-1, 3)
    theta = np.linalg.norm(rvecs, axis=1)
    small = theta < 1e-12
    safe = np.where(small, 1.0, theta)
    k = rvecs / safe[:, None]
    K = np.zeros((len(rvecs), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    R = np.eye(3) + s * K + (1 - c) * (K @ K)
    # first order for tiny angles: I + [r]x
    if np.any(small):
        r = rvecs[small]
        Ks = np.zeros((len(r), 3, 3))
        Ks[:, 0, 1], Ks[:, 0, 2], Ks[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
        Ks[:, 1, 0], Ks[:, 2, 0], Ks[:, 2, 1] = r[:, 2], -r[:, 1], r[:, 0]
        R[small] = np.eye(3) + Ks
    return R


def distort_project(Xc: np.ndarray, intr: np.ndarray) -> np.ndarray:
    """Pixels (… × 2) of camera-frame points Xc (… × 3) with intrinsics rows
    (fx, fy, cx, cy, k1, k2, p1, p2, k3) broadcast against them (… × 9)."""
    x = Xc[..., 0] / Xc[..., 2]
    y = Xc[..., 1] / Xc[..., 2]
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = (intr[..., i] for i in range(9))
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([fx * xd + cx, fy * yd + cy], axis=-1)


@dataclass
class Problem:
    """The corners to fit: observation k is camera ``cam[k]`` seeing view ``view[k]``, its
    corners ``uv[k]`` (n_pts × 2) of the board points ``board`` (n_pts × 3)."""

    board: np.ndarray
    cam: np.ndarray
    view: np.ndarray
    uv: np.ndarray
    n_cams: int
    n_views: int
    fitted: list[list[str]]  # per camera, the distortion terms that are free
    reference: int = 0
    fix_intrinsics: bool = False
    _free: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.board = np.asarray(self.board, float).reshape(-1, 3)
        self.cam = np.asarray(self.cam, int)
        self.view = np.asarray(self.view, int)
        self.uv = np.asarray(self.uv, float).reshape(len(self.cam), -1, 2)
        free = []
        for c in range(self.n_cams):
            base = 15 * c
            if not self.fix_intrinsics:
                free += [base + i for i in range(4)]
                free += [base + 4 + DIST_NAMES.index(n) for n in self.fitted[c]]
            if c != self.reference:
                free += [base + 9 + i for i in range(6)]
        free += list(range(15 * self.n_cams, 15 * self.n_cams + 6 * self.n_views))
        self._free = np.array(free, int)

    @property
    def n_full(self) -> int:
        return 15 * self.n_cams + 6 * self.n_views

    def pack(self, intr: np.ndarray, cam_pose: np.ndarray, view_pose: np.ndarray) -> np.ndarray:
        """The full parameter vector: per camera 9 intrinsics + 6 pose (rvec, t world → camera),
        then per view 6 (rvec, t board → world)."""
        cams = np.hstack(
            [np.asarray(intr, float).reshape(self.n_cams, 9), np.asarray(cam_pose, float).reshape(self.n_cams, 6)]
        )
        return np.r_[cams.ravel(), np.asarray(view_pose, float).ravel()]

    def unpack(self, p: np.ndarray):
        cams = p[: 15 * self.n_cams].reshape(self.n_cams, 15)
        return cams[:, :9], cams[:, 9:], p[15 * self.n_cams :].reshape(self.n_views, 6)

    def project(self, p: np.ndarray) -> np.ndarray:
        """Predicted corners (n_obs × n_pts × 2) for the full parameter vector ``p``."""
        intr, cpose, vpose = self.unpack(p)
        Rv = rodrigues(vpose[:, :3])[self.view]
        Rc = rodrigues(cpose[:, :3])[self.cam]
        Xw = np.einsum("kij,pj->kpi", Rv, self.board) + vpose[self.view, None, 3:]
        Xc = np.einsum("kij,kpj->kpi", Rc, Xw) + cpose[self.cam, None, 3:]
        return distort_project(Xc, intr[self.cam][:, None, :])

    def residuals(self, p: np.ndarray) -> np.ndarray:
        return (self.project(p) - self.uv).ravel()

    def jacobian(self, p: np.ndarray) -> np.ndarray:
        """d residuals / d free parameters (dense), by central differences taken for a whole
        parameter slot at once: slot j of every camera (or every view) is moved together,
        since no residual depends on two cameras or two views."""
        n_pts = len(self.board)
        J = np.zeros((2 * n_pts * len(self.cam), self.n_full))
        rows = np.arange(2 * n_pts * len(self.cam)).reshape(len(self.cam), -1)
        for group, count, width, owner in (
            (0, self.n_cams, 15, self.cam),
            (15 * self.n_cams, self.n_views, 6, self.view),
        ):
            for j in range(width):
                idx = group + width * np.arange(count) + j
                h = 1e-6 * np.maximum(1.0, np.abs(p[idx]))
                up, down = p.copy(), p.copy()
                up[idx] += h
                down[idx] -= h
                diff = (self.project(up) - self.project(down)).reshape(len(self.cam), -1)
                cols = idx[owner]
                J[rows, cols[:, None]] = diff / (2 * h[owner])[:, None]
        return J[:, self._free]


@dataclass
class Solution:
    p: np.ndarray  # the full parameter vector at the solution
    residuals: np.ndarray  # n_obs × n_pts × 2, px
    jac: object  # the (loss-weighted) Jacobian wrt the free parameters
    free: np.ndarray  # indices of the free parameters in p
    cost_start: float
    cost_end: float
    nfev: int
    status: str
    start_rms: float = 0.0  # RMS (px) at the starting point
    converged: bool = True  # False: stopped at max_nfev before a tolerance was met


def adjust(
    problem: Problem, p0: np.ndarray, loss: str = LOSS, f_scale: float | None = None, max_nfev: int = 200
) -> Solution:
    """Least squares over the free parameters from ``p0`` (see the module docstring).

    ``f_scale``: the residual (px) beyond which the robust loss takes over (default ``F_SCALE_PX``),
    so that corners found as well as a corner finder can find them are fitted as in plain least
    squares and only a wrong corner or a wrong view is weighed down (decision 0030).
    """
    p0 = np.asarray(p0, float).copy()
    free = problem._free

    def fun(x):
        p = p0.copy()
        p[free] = x
        return problem.residuals(p)

    r0 = fun(p0[free])
    if f_scale is None:
        f_scale = F_SCALE_PX

    def jac(x):
        p = p0.copy()
        p[free] = x
        return problem.jacobian(p)

    res = least_squares(
        fun,
        p0[free],
        jac=jac,
        loss=loss,
        f_scale=f_scale,
        x_scale="jac",
        method="trf",
        tr_solver="exact",
        max_nfev=max_nfev,
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-10,
    )
    p = p0.copy()
    p[free] = res.x
    return Solution(
        p,
        problem.project(p) - problem.uv,
        res.jac,
        free,
        float(0.5 * r0 @ r0),
        float(res.cost),
        int(res.nfev),
        str(res.message),
        converged=bool(res.status > 0),
    )


def covariance(problem: Problem, sol: Solution) -> dict[int, dict[str, float]]:
    """Per camera the standard deviation of each free parameter (intrinsics in px, distortion
    terms, pose: rotation about the camera's axes in degrees, translation in the square's unit):
    s² (JᵀJ)⁻¹ with s² the residual variance, the board poses eliminated (Schur complement)."""
    J = sol.jac.toarray() if hasattr(sol.jac, "toarray") else np.asarray(sol.jac)
    n_cam_cols = int(np.sum(sol.free < 15 * problem.n_cams))
    N = J.T @ J
    A, B, D = N[:n_cam_cols, :n_cam_cols], N[:n_cam_cols, n_cam_cols:], N[n_cam_cols:, n_cam_cols:]
    # D is block diagonal (6 × 6 per view)
    Dinv_Bt = np.zeros_like(B.T)
    for v in range(problem.n_views):
        s = slice(6 * v, 6 * v + 6)
        Dinv_Bt[s] = np.linalg.solve(D[s, s], B.T[s])
    S = A - B @ Dinv_Bt
    scale = 1.0 / np.sqrt(np.maximum(np.diag(S), 1e-300))
    try:
        inv = np.linalg.inv(S * np.outer(scale, scale))
    except np.linalg.LinAlgError:
        inv = np.linalg.pinv(S * np.outer(scale, scale), rcond=1e-13)
    cov = inv * np.outer(scale, scale)
    r = sol.residuals.ravel()
    dof = max(1, r.size - len(sol.free))
    s2 = float(r @ r) / dof
    out: dict[int, dict[str, float]] = {c: {} for c in range(problem.n_cams)}
    names = (*INTRINSIC_NAMES, *DIST_NAMES, *EXTRINSIC_NAMES)
    for col, j in enumerate(sol.free[:n_cam_cols]):
        c, i = divmod(int(j), 15)
        sd = math.sqrt(max(s2 * cov[col, col], 0.0))
        out[c][names[i]] = math.degrees(sd) if names[i].startswith("r") else sd
    return out
