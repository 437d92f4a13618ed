"""A fast singular value decomposition of 3x3 matrices for Taichi kernels.

``fast_svd(F)`` returns ``(U, sig, V)`` in the convention of Taichi's built-in
``ti.svd(F, ti.f32)``: ``F = U @ sig @ V.transpose()`` with

* ``U``, ``V``: proper rotations (3, 3), determinant +1;
* ``sig``: a diagonal (3, 3) matrix with ``sig[0, 0] >= sig[1, 1] >= |sig[2, 2]|``,
  the first two non-negative and the last negative exactly when ``det F < 0``.

Method. The right singular vectors are the eigenvectors of the symmetric
``A = F^T F``, found without iteration:

1. ``A`` is scaled to unit trace, shifted by a third of the identity and scaled
   by its deviatoric size ``p``, so that ``A = 1/3 I + p B``. The eigenvalues of
   ``B`` are ``2 cos(phi + 2 pi k / 3)`` with ``cos(3 phi) = det(B) / 2``. Only
   the eigenvalue farthest from the other two is used: it is well conditioned
   even when the other two coincide. Its cosine is the root in ``[cos(pi/6), 1]``
   of ``4 c^3 - 3 c = |det(B)| / 2``, from a cubic fit refined by one Newton step
   (error below 1e-8, no ``acos`` or ``cos``).
2. Its eigenvector ``v0`` is the longest cross product of two rows of ``A - lambda I``.
3. In the plane orthogonal to ``v0``, one exact 2x2 Jacobi rotation of a basis
   ``(u, w)`` makes ``F u`` and ``F w`` orthogonal. It is computed from ``F u`` and
   ``F w``, not from ``A``, so that singular values far below the largest one
   keep their float32 accuracy; repeated eigenvalues need no special case (any
   basis of the plane is then an eigenbasis).
4. The columns of ``F V`` are sorted by length, longest first (a swap negates
   one column so that ``V`` stays a rotation), and orthonormalised with cross
   products into ``U``; their lengths along ``U`` are the singular values.

Accuracy: reconstruction, orthogonality and singular values to about 1e-6 of
the largest singular value, near-degenerate and rank-deficient matrices
included, for entries of magnitude about 1e-15 to 1e15 (``F^T F`` must stay
within float32's range). A NaN or infinity in ``F`` gives NaN in the result.
It costs about a third of ``ti.svd`` on the CPU (no loops, no branches).
"""

from __future__ import annotations

import taichi as ti

# Squared lengths below this are treated as zero (a zero matrix, a zero column of F V, a rank-one
# remainder, an isotropic F^T F); any unit vector is then as good as another.
_TINY = 1e-30
# Least-squares cubic fit of cos(acos(r) / 3) on r in [0, 1] (error below 7e-5), lowest order first.
_ROOT_FIT = (0.86609254, 0.16521461, -0.04063035, 0.00937443)


@ti.func
def _unit_or(v, fallback):
    """``v`` normalised, or ``fallback`` (a unit vector) where ``v`` is shorter than sqrt(_TINY).

    A NaN in ``v`` passes through (the comparison is false), so that a broken F stays visible.
    """
    n2 = v.dot(v)
    return ti.select(n2 <= _TINY, fallback, v * ti.rsqrt(n2))


@ti.func
def _orthogonal_unit(v):
    """A unit vector orthogonal to the unit vector ``v`` (``e_y`` for ``v = e_x``, ``e_x`` for ``v = e_z``)."""
    w = ti.select(v[2] * v[2] < 0.5, ti.Vector([-v[1], v[0], 0.0]), ti.Vector([v[2], 0.0, -v[0]]))
    return w * ti.rsqrt(w.dot(w))


@ti.func
def _separated_eigenvector(F):
    """Unit eigenvector (3,) of ``F^T F`` for its eigenvalue farthest from the other two."""
    c0 = ti.Vector([F[0, 0], F[1, 0], F[2, 0]])
    c1 = ti.Vector([F[0, 1], F[1, 1], F[2, 1]])
    c2 = ti.Vector([F[0, 2], F[1, 2], F[2, 2]])
    a00, a11, a22 = c0.dot(c0), c1.dot(c1), c2.dot(c2)
    a01, a02, a12 = c0.dot(c1), c0.dot(c2), c1.dot(c2)
    scale = 1.0 / ti.max(a00 + a11 + a22, _TINY)
    a00, a11, a22, a01, a02, a12 = a00 * scale, a11 * scale, a22 * scale, a01 * scale, a02 * scale, a12 * scale

    # A = I/3 + p B with tr B = 0 and tr B^2 = 6.
    third = 1.0 / 3.0
    d0, d1, d2 = a00 - third, a11 - third, a22 - third
    p = ti.sqrt((d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)) / 6.0)
    inv_p = 1.0 / ti.max(p, _TINY)
    b00, b11, b22, b01, b02, b12 = d0 * inv_p, d1 * inv_p, d2 * inv_p, a01 * inv_p, a02 * inv_p, a12 * inv_p
    half_det = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    r = ti.min(ti.abs(half_det), 1.0)
    c = _ROOT_FIT[0] + r * (_ROOT_FIT[1] + r * (_ROOT_FIT[2] + r * _ROOT_FIT[3]))
    c -= (4.0 * c * c * c - 3.0 * c - r) / (12.0 * c * c - 3.0)
    # The largest eigenvalue when det B >= 0, else the smallest: the one farthest from the other two.
    lam = third + 2.0 * p * ti.select(half_det >= 0.0, c, -c)

    r0 = ti.Vector([a00 - lam, a01, a02])
    r1 = ti.Vector([a01, a11 - lam, a12])
    r2 = ti.Vector([a02, a12, a22 - lam])
    x01, x02, x12 = r0.cross(r1), r0.cross(r2), r1.cross(r2)
    n01, n02, n12 = x01.dot(x01), x02.dot(x02), x12.dot(x12)
    best = ti.select(n02 > n01, x02, x01)
    best = ti.select(n12 > ti.max(n01, n02), x12, best)
    return _unit_or(best, ti.Vector([1.0, 0.0, 0.0]))


@ti.func
def _sort_pair(b_i, b_j, v_i, v_j, n_i, n_j):
    """Swap columns i and j (negating the new j-th) where ``n_i < n_j``, keeping the rotation's determinant."""
    swap = n_i < n_j
    return (ti.select(swap, b_j, b_i), ti.select(swap, -b_i, b_j), ti.select(swap, v_j, v_i),
            ti.select(swap, -v_i, v_j), ti.max(n_i, n_j), ti.min(n_i, n_j))


@ti.func
def fast_svd(F):
    """Singular value decomposition of a 3x3 float32 matrix, the convention of ``ti.svd(F, ti.f32)``.

    Args:
        F: a (3, 3) matrix.

    Returns:
        ``(U, sig, V)``, each (3, 3): rotations ``U`` and ``V`` and the diagonal ``sig``
        (descending, the last entry negative when ``det F < 0``) with ``F = U @ sig @ V^T``.
    """
    v0 = _separated_eigenvector(F)
    u = _orthogonal_unit(v0)
    w = v0.cross(u)
    b0, fu, fw = F @ v0, F @ u, F @ w
    # The rotation within [-pi/4, pi/4] of the plane (u, w) that makes F u and F w orthogonal: the 2x2
    # eigenproblem of F^T F in that plane, from F itself, which keeps small singular values accurate.
    x = fu.dot(fu) - fw.dot(fw)
    y = 2.0 * fu.dot(fw)
    t = ti.select(x >= 0.0, y, -y) / ti.max(ti.sqrt(x * x + y * y) + ti.abs(x), _TINY)
    cos_t = ti.rsqrt(1.0 + t * t)
    sin_t = t * cos_t
    v1, v2 = cos_t * u + sin_t * w, cos_t * w - sin_t * u
    b1, b2 = cos_t * fu + sin_t * fw, cos_t * fw - sin_t * fu
    n0, n1, n2 = b0.dot(b0), b1.dot(b1), b2.dot(b2)
    b0, b1, v0, v1, n0, n1 = _sort_pair(b0, b1, v0, v1, n0, n1)
    b0, b2, v0, v2, n0, n2 = _sort_pair(b0, b2, v0, v2, n0, n2)
    b1, b2, v1, v2, _, _ = _sort_pair(b1, b2, v1, v2, n1, n2)

    # Gram-Schmidt through cross products: u0 x b1 is orthogonal to u0 however close b1 comes to it, and
    # its length is that of b1's part orthogonal to u0 (the second singular value).
    u0 = _unit_or(b0, ti.Vector([1.0, 0.0, 0.0]))
    normal = u0.cross(b1)
    u2 = _unit_or(normal, _orthogonal_unit(u0))
    u1 = u2.cross(u0)
    sig = ti.Matrix([[ti.sqrt(n0), 0.0, 0.0], [0.0, ti.sqrt(normal.dot(normal)), 0.0], [0.0, 0.0, u2.dot(b2)]])
    return ti.Matrix.cols([u0, u1, u2]), sig, ti.Matrix.cols([v0, v1, v2])
