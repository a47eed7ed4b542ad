"""The physics kernel (semi-implicit Euler with a Karnopp stick band, two-inertia backlash) and the sensor kernels
(encoder reading from the physics history, limit checks); numba when available."""

from __future__ import annotations

import math

import numpy as np

try:  # numba is optional: the kernel is plain Python-compatible code
    from numba import njit
except Exception:  # pragma: no cover
    def njit(*a, **k):
        if a and callable(a[0]):
            return a[0]
        return lambda f: f

@njit(cache=True)
def _shape(x, code, delta):
    if code == 1:
        return math.exp(-(x ** delta))
    if code == 2:
        return 1.0 / (1.0 + x * x)
    return 0.0


@njit(cache=True)
def _kinetic(v, fr, i, g):
    # fr columns: Fc+, Fc-, B+, B-, Fs+, Fs-, vs, shape, delta ; g: drift multiplier
    if v > 0.0:
        s = _shape(v / fr[i, 6], int(fr[i, 7]), fr[i, 8])
        return -g * (fr[i, 0] + (fr[i, 4] - fr[i, 0]) * s + fr[i, 2] * v)
    s = _shape(-v / fr[i, 6], int(fr[i, 7]), fr[i, 8])
    return g * (fr[i, 1] + (fr[i, 5] - fr[i, 1]) * s - fr[i, 3] * v)


@njit(cache=True)
def _ripple(q, rip):
    a = 0.0
    for k in range(3):
        if rip[3 + k] != 0.0:
            a += rip[3 + k] * math.sin(2.0 * math.pi * (k + 1) * q / rip[2] + rip[6 + k])
    return rip[1] * a


@njit(cache=True)
def _drift_gain(t, dri):
    if dri[0] < 0:
        return 1.0
    if dri[2] == 0:
        return 1.0 + dri[1] * min(t / dri[4], 1.0)
    return 1.0 + dri[1] * math.tanh(t / dri[3])


@njit(cache=True)
def _coupling(qr, vr, ql, vl, bkl):
    # unilateral spring-damper with dead band +-b; positive = pushes the link forward
    b, k, c = bkl[1], bkl[2], bkl[3]
    d = qr - ql
    dd = vr - vl
    if d > b:
        f = k * (d - b) + c * dd
        return f if f > 0.0 else 0.0
    if d < -b:
        f = k * (d + b) + c * dd
        return f if f < 0.0 else 0.0
    return 0.0


@njit(cache=True)
def _matvec(A, y, n, out):
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += A[i, j] * y[j]
        out[i] = s


@njit(cache=True)
def _spd_solve(A, idx, ns, rhs, L, out):
    """Solve A[idx, idx] z = rhs by Cholesky (the sub-matrix of M^-1 is symmetric positive definite)."""
    for p in range(ns):
        for r in range(p + 1):
            s = A[idx[p], idx[r]]
            for k in range(r):
                s -= L[p, k] * L[r, k]
            if p == r:
                L[p, p] = math.sqrt(s)
            else:
                L[p, r] = s / L[r, r]
    for p in range(ns):
        s = rhs[p]
        for k in range(p):
            s -= L[p, k] * out[k]
        out[p] = s / L[p, p]
    for p in range(ns - 1, -1, -1):
        s = out[p]
        for k in range(p + 1, ns):
            s -= L[k, p] * out[k]
        out[p] = s / L[p, p]


@njit(cache=True)
def phys_step(x, tau_m, Minv, nle, t, fr, rip, dri, bkl, h, band, stuck, W):
    """One semi-implicit Euler step with Karnopp friction. x = [q(7), v(7), qr, vr], updated in place.

    stuck[i] is set to 1 for the DOFs (7 joints + rotor) held by static friction during this step.
    W: float workspace (8, 40).
    """
    jb = int(bkl[0])
    n = 8 if jb >= 0 else 7
    A = W[:, 0:8]
    L = W[:, 8:16]
    b = W[:, 16]
    v = W[:, 17]
    f = W[:, 18]
    gain = W[:, 19]
    a0 = W[:, 20]
    a = W[:, 21]
    rhs = W[:, 22]
    fs = W[:, 23]
    vnew = W[:, 24]
    bf = W[:, 25]
    mode = stuck  # reused as the mode array (0 kinetic, 1 stuck, 2 broke away at the static level)
    idx = np.empty(8, np.int64)
    for i in range(8):
        for j in range(8):
            A[i, j] = 0.0
    for i in range(7):
        for j in range(7):
            A[i, j] = Minv[i, j]
        b[i] = tau_m[i] - nle[i]
        v[i] = x[7 + i]
    if jb >= 0:
        A[7, 7] = 1.0 / bkl[4]
        v[7] = x[15]
        tc = _coupling(x[14], x[15], x[jb], x[7 + jb], bkl)
        b[jb] = tc - nle[jb]
        b[7] = tau_m[jb] - tc
    jr = int(rip[0])
    if jr >= 0:
        b[jr] += _ripple(x[jr], rip)
    jd = int(dri[0])
    for i in range(8):
        gain[i] = 1.0
    if jd >= 0:
        gd = _drift_gain(t, dri)
        gain[jd] = gd
        if jb == jd:
            gain[7] = gd
    for i in range(n):
        f[i] = 0.0
        if abs(v[i]) < band:
            mode[i] = 1
        else:
            mode[i] = 0
            f[i] = _kinetic(v[i], fr, i, gain[i])
    for outer in range(2):
        for i in range(n):
            if mode[i] == 2:
                mode[i] = 1
                f[i] = 0.0
        for _it in range(n + 1):
            ns = 0
            for i in range(n):
                if mode[i] == 1:
                    idx[ns] = i
                    ns += 1
                    f[i] = 0.0
            for i in range(n):
                bf[i] = b[i] + f[i]
            _matvec(A, bf, n, a0)
            if ns == 0:
                for i in range(n):
                    a[i] = a0[i]
                break
            for p in range(ns):
                rhs[p] = -v[idx[p]] / h - a0[idx[p]]
            _spd_solve(A, idx, ns, rhs, L, fs)
            worst = -1
            wratio = 1.0
            for p in range(ns):
                i = idx[p]
                lim = fr[i, 4] * gain[i] if fs[p] < 0.0 else fr[i, 5] * gain[i]
                r = abs(fs[p]) / lim if lim > 0.0 else 1e300
                if r > wratio:
                    wratio = r
                    worst = p
            if worst < 0:
                for p in range(ns):
                    f[idx[p]] = fs[p]
                for i in range(n):
                    bf[i] = b[i] + f[i]
                _matvec(A, bf, n, a)
                break
            i = idx[worst]
            mode[i] = 2
            f[i] = -fr[i, 4] * gain[i] if fs[worst] < 0.0 else fr[i, 5] * gain[i]
            for i in range(n):
                bf[i] = b[i] + f[i]
            _matvec(A, bf, n, a)
        for i in range(n):
            vnew[i] = v[i] + h * a[i]
            if mode[i] == 1:
                vnew[i] = 0.0
        if outer == 1:
            break
        crossed = False
        for i in range(n):
            if mode[i] == 0 and vnew[i] * v[i] < 0.0:
                mode[i] = 1
                f[i] = 0.0
                crossed = True
        if not crossed:
            break
    for i in range(7):
        x[7 + i] = vnew[i]
        x[i] += h * vnew[i]
        stuck[i] = 1 if mode[i] == 1 else 0
    if jb >= 0:
        x[15] = vnew[7]
        x[14] += h * vnew[7]
        stuck[7] = 1 if mode[7] == 1 else 0
    else:
        stuck[7] = 0



@njit(cache=True)
def _measure(X, cq, cv, n_valid, tau, h, q_init, j2mp, j2mp_inv, res, phase, out):
    """Encoder reading at time tau: drive-side positions from the physics history X (rows 0..n_valid) by cubic
    Hermite interpolation, to motor angles, quantised (bin centre, per-motor bin phase), back to joint angles."""
    qd = np.empty(7)
    if tau <= 0.0:
        for c in range(7):
            qd[c] = q_init[c]
    else:
        s = tau / h
        i = int(s)
        if i >= n_valid:
            for c in range(7):
                qd[c] = X[n_valid, cq[c]]
        else:
            u = s - i
            u2 = u * u
            u3 = u2 * u
            for c in range(7):
                p0, p1 = X[i, cq[c]], X[i + 1, cq[c]]
                m0, m1 = X[i, cv[c]] * h, X[i + 1, cv[c]] * h
                qd[c] = ((2 * u3 - 3 * u2 + 1) * p0 + (u3 - 2 * u2 + u) * m0 + (-2 * u3 + 3 * u2) * p1
                         + (u3 - u2) * m1)
    mq = np.empty(7)
    for r in range(7):
        m = 0.0
        for c in range(7):
            m += j2mp[r, c] * qd[c]
        mq[r] = (math.floor(m / res + phase[r]) - phase[r] + 0.5) * res
    for r in range(7):
        s = 0.0
        for c in range(7):
            s += j2mp_inv[r, c] * mq[c]
        out[r] = s


@njit(cache=True)
def _limits_code(x, qmin, qmax):
    for i in range(16):
        if not math.isfinite(x[i]):
            return 1
    for i in range(7):
        if x[i] < qmin[i] - 0.1 or x[i] > qmax[i] + 0.1:
            return 2
        if abs(x[7 + i]) > 5.0:
            return 3
    return 0


