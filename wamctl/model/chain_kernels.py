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
def _joint_transform(rot, trans, qi, E, p):
    """Rotation ``E`` (parent axes -> child axes) and translation ``p`` (child origin in the parent) of a joint."""
    _joint_transform_cs(rot, trans, np.cos(qi), np.sin(qi), E, p)


@njit(cache=True, inline="always")
def _joint_transform_cs(rot, trans, c, s, E, p):
    """:func:`_joint_transform` from ``cos q``, ``sin q``."""
    for r in range(3):
        # child axes in the parent: rot @ Rz(q); E is its transpose
        a0 = rot[r, 0] * c + rot[r, 1] * s
        a1 = -rot[r, 0] * s + rot[r, 1] * c
        E[0, r] = a0
        E[1, r] = a1
        E[2, r] = rot[r, 2]
        p[r] = trans[r]


@njit(cache=True)
def _motion_to_child(E, p, vin, vout):
    """``vout = X vin``: a motion vector [linear; angular] from the parent's frame to the child's."""
    wl0 = vin[0] + vin[4] * p[2] - vin[5] * p[1]        # v + w x p  (equals v - p x w)
    wl1 = vin[1] + vin[5] * p[0] - vin[3] * p[2]
    wl2 = vin[2] + vin[3] * p[1] - vin[4] * p[0]
    for r in range(3):
        vout[r] = E[r, 0] * wl0 + E[r, 1] * wl1 + E[r, 2] * wl2
        vout[3 + r] = E[r, 0] * vin[3] + E[r, 1] * vin[4] + E[r, 2] * vin[5]


@njit(cache=True)
def _force_to_parent_add(E, p, fin, fout):
    """``fout += X^T fin``: a force vector [force; moment] from the child's frame to the parent's, accumulated."""
    f0 = E[0, 0] * fin[0] + E[1, 0] * fin[1] + E[2, 0] * fin[2]
    f1 = E[0, 1] * fin[0] + E[1, 1] * fin[1] + E[2, 1] * fin[2]
    f2 = E[0, 2] * fin[0] + E[1, 2] * fin[1] + E[2, 2] * fin[2]
    n0 = E[0, 0] * fin[3] + E[1, 0] * fin[4] + E[2, 0] * fin[5]
    n1 = E[0, 1] * fin[3] + E[1, 1] * fin[4] + E[2, 1] * fin[5]
    n2 = E[0, 2] * fin[3] + E[1, 2] * fin[4] + E[2, 2] * fin[5]
    fout[0] += f0
    fout[1] += f1
    fout[2] += f2
    fout[3] += n0 + p[1] * f2 - p[2] * f1
    fout[4] += n1 + p[2] * f0 - p[0] * f2
    fout[5] += n2 + p[0] * f1 - p[1] * f0


@njit(cache=True)
def rnea(rot, trans, inertia, armature, gravity, q, qd, qdd, tau, work):
    """Inverse dynamics ``tau = B(q) qdd + C(q, qd) qd + g(q)`` (armature included) into ``tau`` (n,).

    ``work``: (n, 4, 6) scratch (velocity, acceleration, force, and cos/sin of q of each body)."""
    n = q.shape[0]
    E = np.empty((3, 3))
    p = np.empty(3)
    vp = np.zeros(6)
    ap = np.zeros(6)
    for k in range(3):
        ap[k] = -gravity[k]          # the base accelerates against gravity (Featherstone's trick)
    tmp = np.empty(6)
    for i in range(n):
        c, s = np.cos(q[i]), np.sin(q[i])
        work[i, 3, 0] = c          # kept for the backward pass
        work[i, 3, 1] = s
        _joint_transform_cs(rot[i], trans[i], c, s, E, p)
        v = work[i, 0]
        a = work[i, 1]
        f = work[i, 2]
        _motion_to_child(E, p, vp, v)
        v[5] += qd[i]
        _motion_to_child(E, p, ap, a)
        # a += v x_m (S qd): S = e_z angular; (w x 0) + (vl x ez qd) linear, w x ez qd angular
        a[0] += v[1] * qd[i]
        a[1] -= v[0] * qd[i]
        a[3] += v[4] * qd[i]
        a[4] -= v[3] * qd[i]
        a[5] += qdd[i]
        # f = I a + v x_f (I v)
        Ii = inertia[i]
        for r in range(6):
            acc_a = 0.0
            acc_v = 0.0
            for c in range(6):
                acc_a += Ii[r, c] * a[c]
                acc_v += Ii[r, c] * v[c]
            f[r] = acc_a
            tmp[r] = acc_v
        # v x_f h, h = I v: [w x hl; w x ha + vl x hl]
        f[0] += v[4] * tmp[2] - v[5] * tmp[1]
        f[1] += v[5] * tmp[0] - v[3] * tmp[2]
        f[2] += v[3] * tmp[1] - v[4] * tmp[0]
        f[3] += v[4] * tmp[5] - v[5] * tmp[4] + v[1] * tmp[2] - v[2] * tmp[1]
        f[4] += v[5] * tmp[3] - v[3] * tmp[5] + v[2] * tmp[0] - v[0] * tmp[2]
        f[5] += v[3] * tmp[4] - v[4] * tmp[3] + v[0] * tmp[1] - v[1] * tmp[0]
        for r in range(6):
            vp[r] = v[r]
            ap[r] = a[r]
    for i in range(n - 1, -1, -1):
        f = work[i, 2]
        tau[i] = f[5] + armature[i] * qdd[i]
        if i > 0:
            _joint_transform_cs(rot[i], trans[i], work[i, 3, 0], work[i, 3, 1], E, p)
            _force_to_parent_add(E, p, f, work[i - 1, 2])


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
        for r in range(3):
            W[1, r] = rot[i, r, 0] * c + rot[i, r, 1] * s     # E = (rot Rz(q))^T, as _joint_transform_cs
            W[2, r] = -rot[i, r, 0] * s + rot[i, r, 1] * c
            W[3, r] = rot[i, r, 2]
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
