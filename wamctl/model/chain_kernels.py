"""Rigid-body algorithms of a serial chain of revolute-z joints in numba (no pinocchio at run time).

The chain is described by arrays (:meth:`wamctl.model.dynamics.WamDynamics.chain_arrays` takes them from the
pinocchio model, payload included), for n joints:

* ``rot`` (n, 3, 3), ``trans`` (n, 3): joint i's fixed placement in its parent joint's frame (joint 0's parent
  is the base); joint i's frame is that placement turned by ``q_i`` about its z axis.
* ``inertia`` (n, 6, 6): body i's spatial inertia about joint i's origin in joint i's axes, pinocchio's order
  (linear first): ``[[m 1, -m [c]x], [m [c]x, I_c - m [c]x [c]x]]``.
* ``armature`` (n,): reflected rotor inertia, added to the diagonal of the mass matrix (and ``armature qdd`` to
  the inverse dynamics), as pinocchio does.
* ``gravity`` (3,): the gravity vector in the base frame, m/s^2.

Algorithms (Featherstone, "Rigid Body Dynamics Algorithms", 2008): RNEA (inverse dynamics; with ``qdd = 0`` the
nonlinear effects ``C qd + g``; with ``qd = qdd = 0`` the gravity torque), CRBA (the mass matrix with armature),
its inverse through a Cholesky factorisation, forward dynamics ``B^-1 (tau - C qd - g)``. Generic over n.
Every kernel takes a preallocated workspace so the closed loop's hot path allocates nothing.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _rotation_cs(R, c, s):
    """The 9 entries of ``E``, row by row: the rotation from the parent's axes to the child's of a joint whose fixed
    placement has rotation ``R``, turned by ``q`` about its z (``cos q``, ``sin q``): ``E = (R Rz(q))^T``."""
    return (R[0, 0] * c + R[0, 1] * s, R[1, 0] * c + R[1, 1] * s, R[2, 0] * c + R[2, 1] * s,
            -R[0, 0] * s + R[0, 1] * c, -R[1, 0] * s + R[1, 1] * c, -R[2, 0] * s + R[2, 1] * c,
            R[0, 2], R[1, 2], R[2, 2])


@njit(cache=True)
def rnea(rot, trans, inertia, armature, gravity, q, qd, qdd, tau, work):
    """Inverse dynamics ``tau = B(q) qdd + C(q, qd) qd + g(q)`` (armature included) into ``tau`` (n,).

    ``work``: (n, 4, 6) scratch (velocity, acceleration, force, and cos/sin of q of each body); nothing else is
    allocated (the closed loop calls this three times a tick)."""
    n = q.shape[0]
    for i in range(n):
        c, s = np.cos(q[i]), np.sin(q[i])
        work[i, 3, 0] = c          # kept for the backward pass
        work[i, 3, 1] = s
        if i == 0:                 # the base is at rest and accelerates against gravity (Featherstone's trick)
            u0 = u1 = u2 = w0 = w1 = w2 = 0.0
            b0, b1, b2 = -gravity[0], -gravity[1], -gravity[2]
            b3 = b4 = b5 = 0.0
        else:
            vp, ap = work[i - 1, 0], work[i - 1, 1]
            u0, u1, u2, w0, w1, w2 = vp[0], vp[1], vp[2], vp[3], vp[4], vp[5]
            b0, b1, b2, b3, b4, b5 = ap[0], ap[1], ap[2], ap[3], ap[4], ap[5]
        e00, e01, e02, e10, e11, e12, e20, e21, e22 = _rotation_cs(rot[i], c, s)
        px, py, pz = trans[i, 0], trans[i, 1], trans[i, 2]
        v = work[i, 0]
        a = work[i, 1]
        f = work[i, 2]
        # X (parent -> child) of the parent's motion: linear part v + w x p, then both parts in the child's axes
        l0, l1, l2 = u0 + w1 * pz - w2 * py, u1 + w2 * px - w0 * pz, u2 + w0 * py - w1 * px
        v[0] = e00 * l0 + e01 * l1 + e02 * l2
        v[1] = e10 * l0 + e11 * l1 + e12 * l2
        v[2] = e20 * l0 + e21 * l1 + e22 * l2
        v[3] = e00 * w0 + e01 * w1 + e02 * w2
        v[4] = e10 * w0 + e11 * w1 + e12 * w2
        v[5] = e20 * w0 + e21 * w1 + e22 * w2 + qd[i]
        l0, l1, l2 = b0 + b4 * pz - b5 * py, b1 + b5 * px - b3 * pz, b2 + b3 * py - b4 * px
        a[0] = e00 * l0 + e01 * l1 + e02 * l2
        a[1] = e10 * l0 + e11 * l1 + e12 * l2
        a[2] = e20 * l0 + e21 * l1 + e22 * l2
        a[3] = e00 * b3 + e01 * b4 + e02 * b5
        a[4] = e10 * b3 + e11 * b4 + e12 * b5
        a[5] = e20 * b3 + e21 * b4 + e22 * b5
        # a += v x_m (S qd): S = e_z angular; (w x 0) + (vl x ez qd) linear, w x ez qd angular
        a[0] += v[1] * qd[i]
        a[1] -= v[0] * qd[i]
        a[3] += v[4] * qd[i]
        a[4] -= v[3] * qd[i]
        a[5] += qdd[i]
        # f = I a + v x_f h, h = I v: [w x hl; w x ha + vl x hl]
        Ii = inertia[i]
        for r in range(6):
            acc = 0.0
            for cc in range(6):
                acc += Ii[r, cc] * v[cc]
            f[r] = acc
        h0, h1, h2, h3, h4, h5 = f[0], f[1], f[2], f[3], f[4], f[5]
        for r in range(6):
            acc = 0.0
            for cc in range(6):
                acc += Ii[r, cc] * a[cc]
            f[r] = acc
        f[0] += v[4] * h2 - v[5] * h1
        f[1] += v[5] * h0 - v[3] * h2
        f[2] += v[3] * h1 - v[4] * h0
        f[3] += v[4] * h5 - v[5] * h4 + v[1] * h2 - v[2] * h1
        f[4] += v[5] * h3 - v[3] * h5 + v[2] * h0 - v[0] * h2
        f[5] += v[3] * h4 - v[4] * h3 + v[0] * h1 - v[1] * h0
    for i in range(n - 1, -1, -1):
        f = work[i, 2]
        tau[i] = f[5] + armature[i] * qdd[i]
        if i > 0:              # f_parent += X^T f: E^T of both parts, then the moment of the force about p
            e00, e01, e02, e10, e11, e12, e20, e21, e22 = _rotation_cs(rot[i], work[i, 3, 0], work[i, 3, 1])
            px, py, pz = trans[i, 0], trans[i, 1], trans[i, 2]
            g0 = e00 * f[0] + e10 * f[1] + e20 * f[2]
            g1 = e01 * f[0] + e11 * f[1] + e21 * f[2]
            g2 = e02 * f[0] + e12 * f[1] + e22 * f[2]
            fp = work[i - 1, 2]
            fp[0] += g0
            fp[1] += g1
            fp[2] += g2
            fp[3] += e00 * f[3] + e10 * f[4] + e20 * f[5] + py * g2 - pz * g1
            fp[4] += e01 * f[3] + e11 * f[4] + e21 * f[5] + pz * g0 - px * g2
            fp[5] += e02 * f[3] + e12 * f[4] + e22 * f[5] + px * g1 - py * g0


@njit(cache=True)
def crba(rot, trans, inertia, armature, q, M, work):
    """Joint-space mass matrix ``B(q)`` with armature, both triangles, into ``M`` (n, n).

    ``work``: (n, 6, 6) scratch. Row block of body i: its composite inertia about joint i's origin as mass
    ``work[i, 0, 0]``, first moment ``h = m c`` in ``work[i, 0, 1:4]`` and rotational inertia about the origin in
    ``work[i, 3:6, 3:6]``; joint i's ``E`` in ``work[i, 1:4, 0:3]`` and ``p`` in ``work[i, 4, 0:3]``. Carrying a
    composite inertia to the parent is done in that form (``R I R^T`` and the parallel-axis terms), not through
    the 6x6 transform; nothing is allocated."""
    n = q.shape[0]
    for i in range(n):
        W = work[i]
        c, s = np.cos(q[i]), np.sin(q[i])
        (W[1, 0], W[1, 1], W[1, 2], W[2, 0], W[2, 1], W[2, 2],
         W[3, 0], W[3, 1], W[3, 2]) = _rotation_cs(rot[i], c, s)
        for r in range(3):
            W[4, r] = trans[i, r]
        Ii = inertia[i]
        W[0, 0] = Ii[0, 0]
        W[0, 1] = Ii[5, 1]           # [h]x sits in the lower left block: h = (I[5,1], I[3,2], I[4,0])
        W[0, 2] = Ii[3, 2]
        W[0, 3] = Ii[4, 0]
        for r in range(3, 6):
            for cc in range(3, 6):
                W[r, cc] = Ii[r, cc]
    for i in range(n - 1, -1, -1):
        W = work[i]
        # column i: F = Ic S (S = angular z): (-h1, h0, 0, I[:, 2]), carried to each ancestor
        f0, f1, f2 = -W[0, 2], W[0, 1], 0.0
        n0, n1, n2 = W[3, 5], W[4, 5], W[5, 5]
        M[i, i] = n2 + armature[i]
        for j in range(i - 1, -1, -1):
            X = work[j + 1]          # E rows 1..3, p row 4 of joint j + 1
            g0 = X[1, 0] * f0 + X[2, 0] * f1 + X[3, 0] * f2
            g1 = X[1, 1] * f0 + X[2, 1] * f1 + X[3, 1] * f2
            g2 = X[1, 2] * f0 + X[2, 2] * f1 + X[3, 2] * f2
            m0 = X[1, 0] * n0 + X[2, 0] * n1 + X[3, 0] * n2
            m1 = X[1, 1] * n0 + X[2, 1] * n1 + X[3, 1] * n2
            m2 = X[1, 2] * n0 + X[2, 2] * n1 + X[3, 2] * n2
            px, py, pz = X[4, 0], X[4, 1], X[4, 2]
            f0, f1, f2 = g0, g1, g2
            n0 = m0 + py * g2 - pz * g1
            n1 = m1 + pz * g0 - px * g2
            n2 = m2 + px * g1 - py * g0
            M[i, j] = n2
            M[j, i] = n2
        if i > 0:
            _composite_to_parent_add(W, work[i - 1])


@njit(cache=True, inline="always")
def _composite_to_parent_add(W, P):
    """Add body block ``W``'s composite inertia (about its joint's origin, its axes) to the parent's block ``P``
    (about the parent joint's origin, the parent's axes): with ``R = E^T`` and ``p`` the joint's placement,
    ``h' = R h``, ``I' = R I R^T``, then about the parent's origin ``h_P = h' + m p`` and
    ``I_P = I' - (p h'^T + h' p^T) + 2 (h'.p) 1 - m (p p^T - |p|^2 1)``."""
    m = W[0, 0]
    px, py, pz = W[4, 0], W[4, 1], W[4, 2]
    # h' = E^T h (E is work rows 1..3)
    hx = W[1, 0] * W[0, 1] + W[2, 0] * W[0, 2] + W[3, 0] * W[0, 3]
    hy = W[1, 1] * W[0, 1] + W[2, 1] * W[0, 2] + W[3, 1] * W[0, 3]
    hz = W[1, 2] * W[0, 1] + W[2, 2] * W[0, 2] + W[3, 2] * W[0, 3]
    # T = I E (3x3), then I' = E^T T
    t00 = W[3, 3] * W[1, 0] + W[3, 4] * W[2, 0] + W[3, 5] * W[3, 0]
    t01 = W[3, 3] * W[1, 1] + W[3, 4] * W[2, 1] + W[3, 5] * W[3, 1]
    t02 = W[3, 3] * W[1, 2] + W[3, 4] * W[2, 2] + W[3, 5] * W[3, 2]
    t10 = W[4, 3] * W[1, 0] + W[4, 4] * W[2, 0] + W[4, 5] * W[3, 0]
    t11 = W[4, 3] * W[1, 1] + W[4, 4] * W[2, 1] + W[4, 5] * W[3, 1]
    t12 = W[4, 3] * W[1, 2] + W[4, 4] * W[2, 2] + W[4, 5] * W[3, 2]
    t20 = W[5, 3] * W[1, 0] + W[5, 4] * W[2, 0] + W[5, 5] * W[3, 0]
    t21 = W[5, 3] * W[1, 1] + W[5, 4] * W[2, 1] + W[5, 5] * W[3, 1]
    t22 = W[5, 3] * W[1, 2] + W[5, 4] * W[2, 2] + W[5, 5] * W[3, 2]
    i00 = W[1, 0] * t00 + W[2, 0] * t10 + W[3, 0] * t20
    i01 = W[1, 0] * t01 + W[2, 0] * t11 + W[3, 0] * t21
    i02 = W[1, 0] * t02 + W[2, 0] * t12 + W[3, 0] * t22
    i11 = W[1, 1] * t01 + W[2, 1] * t11 + W[3, 1] * t21
    i12 = W[1, 1] * t02 + W[2, 1] * t12 + W[3, 1] * t22
    i22 = W[1, 2] * t02 + W[2, 2] * t12 + W[3, 2] * t22
    hp = hx * px + hy * py + hz * pz
    pp = px * px + py * py + pz * pz
    d = 2.0 * hp + m * pp
    i00 += d - 2.0 * px * hx - m * px * px
    i11 += d - 2.0 * py * hy - m * py * py
    i22 += d - 2.0 * pz * hz - m * pz * pz
    i01 += -(px * hy + hx * py) - m * px * py
    i02 += -(px * hz + hx * pz) - m * px * pz
    i12 += -(py * hz + hy * pz) - m * py * pz
    P[0, 0] += m
    P[0, 1] += hx + m * px
    P[0, 2] += hy + m * py
    P[0, 3] += hz + m * pz
    P[3, 3] += i00
    P[4, 4] += i11
    P[5, 5] += i22
    P[3, 4] += i01
    P[4, 3] += i01
    P[3, 5] += i02
    P[5, 3] += i02
    P[4, 5] += i12
    P[5, 4] += i12


@njit(cache=True)
def cholesky_inverse(M, L, out):
    """``out = M^-1`` of a symmetric positive definite ``M`` (both triangles) through ``M = L L^T``."""
    n = M.shape[0]
    for j in range(n):
        s = M[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            s = M[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
        for i in range(j):
            L[i, j] = 0.0
    # inverse of L (lower), in place into out's lower triangle first
    for j in range(n):
        for i in range(n):
            out[i, j] = 0.0
    for c in range(n):
        for i in range(c, n):
            s = 1.0 if i == c else 0.0
            for k in range(c, i):
                s -= L[i, k] * out[k, c]
            out[i, c] = s / L[i, i]
    # M^-1 = L^-T L^-1, symmetric; compute the upper triangle from the lower triangle of L^-1, then mirror
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for k in range(j, n):
                s += out[k, i] * out[k, j]
            L[i, j] = s
    for i in range(n):
        for j in range(i, n):
            out[i, j] = L[i, j]
            out[j, i] = L[i, j]


@njit(cache=True)
def forward_dynamics(rot, trans, inertia, armature, gravity, q, qd, tau, qdd, work_rnea, work_crba, M, L, Minv):
    """``qdd = B^-1 (tau - C qd - g)`` into ``qdd`` (n,)."""
    n = q.shape[0]
    zero = np.zeros(n)
    nle = np.empty(n)
    rnea(rot, trans, inertia, armature, gravity, q, qd, zero, nle, work_rnea)
    crba(rot, trans, inertia, armature, q, M, work_crba)
    cholesky_inverse(M, L, Minv)
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += Minv[i, j] * (tau[j] - nle[j])
        qdd[i] = s


class ChainDynamics:
    """The kernels bound to one chain's arrays, with their workspaces: numpy in, numpy out (tests, tools).

    ``ChainDynamics(*dyn.chain_arrays())`` for a :class:`~wamctl.model.dynamics.WamDynamics` ``dyn``."""

    def __init__(self, rot, trans, inertia, armature, gravity):
        self.rot = np.ascontiguousarray(rot, dtype=float)
        self.trans = np.ascontiguousarray(trans, dtype=float)
        self.inertia = np.ascontiguousarray(inertia, dtype=float)
        self.armature = np.ascontiguousarray(armature, dtype=float)
        self.gravity_m_s2 = np.ascontiguousarray(gravity, dtype=float)
        self.n = len(self.armature)
        self._wr = np.zeros((self.n, 4, 6))
        self._wc = np.zeros((self.n, 6, 6))

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        out = np.empty(self.n)
        rnea(self.rot, self.trans, self.inertia, self.armature, self.gravity_m_s2, np.asarray(q, float),
             np.asarray(qd, float), np.asarray(qdd, float), out, self._wr)
        return out

    def nonlinear_effects(self, q, qd) -> np.ndarray:
        return self.inverse_dynamics(q, qd, np.zeros(self.n))

    def gravity(self, q) -> np.ndarray:
        z = np.zeros(self.n)
        return self.inverse_dynamics(q, z, z)

    def mass_matrix(self, q) -> np.ndarray:
        M = np.empty((self.n, self.n))
        crba(self.rot, self.trans, self.inertia, self.armature, np.asarray(q, float), M, self._wc)
        return M

    def mass_matrix_inverse(self, q) -> np.ndarray:
        out = np.empty((self.n, self.n))
        cholesky_inverse(self.mass_matrix(q), np.empty((self.n, self.n)), out)
        return out

    def forward_dynamics(self, q, qd, tau) -> np.ndarray:
        out = np.empty(self.n)
        nn = (self.n, self.n)
        forward_dynamics(self.rot, self.trans, self.inertia, self.armature, self.gravity_m_s2,
                         np.asarray(q, float), np.asarray(qd, float), np.asarray(tau, float), out, self._wr,
                         self._wc, np.empty(nn), np.empty(nn), np.empty(nn))
        return out
