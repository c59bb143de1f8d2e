"""Small dense and block-tridiagonal linear algebra as plain XLA ops (batch under ``vmap``).

No LAPACK here: jaxlib's CPU triangular-solve and Cholesky kernels split a vmapped batch over
XLA's intra-op thread pool (``ParallelBatchMap``) and, with jaxlib 0.10 on a small machine, can
wait forever for tasks the pool never runs (seen: every worker idle, the kernel blocked in
``lapack_strsm_ffi``). These loops are plain XLA ops and batch like any other.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["lower_inverse", "cholesky", "spd_inverse", "small_inverse", "block_factor", "block_solve"]


def _substitution_inverse(L):
    """Inverse of a lower-triangular ``(n, n)`` matrix by forward substitution, row by row."""
    n = L.shape[-1]
    eye = jnp.eye(n, dtype=L.dtype)

    def row(i, X):
        return X.at[i].set((eye[i] - L[i] @ X) / L[i, i])  # rows >= i of X are still zero

    return jax.lax.fori_loop(0, n, row, jnp.zeros_like(L))


def lower_inverse(L):
    """Inverse of a lower-triangular ``(n, n)`` matrix by blocks (matrix products; blocks of
    at most 32 rows by forward substitution): on XLA's CPU backend far faster than one
    ``n x n`` substitution."""
    n = L.shape[-1]
    if n <= 32:
        return _substitution_inverse(L)
    k = n // 2
    Ai, Ci = lower_inverse(L[:k, :k]), lower_inverse(L[k:, k:])
    low = -Ci @ (L[k:, :k] @ Ai)
    return jnp.concatenate([jnp.concatenate([Ai, jnp.zeros((k, n - k), L.dtype)], 1), jnp.concatenate([low, Ci], 1)], 0)


def cholesky(K):
    """Lower Cholesky factor of a symmetric positive definite ``(n, n)`` matrix, column by column."""
    n = K.shape[-1]
    idx = jnp.arange(n)

    def col(j, L):
        v = K[:, j] - L @ L[j]  # columns >= j of L are still zero
        d = jnp.sqrt(jnp.maximum(v[j], jnp.finfo(K.dtype).tiny))
        return L.at[:, j].set(jnp.where(idx > j, v / d, jnp.where(idx == j, d, 0.0)))

    return jax.lax.fori_loop(0, n, col, jnp.zeros_like(K))


def spd_inverse(K):
    """Inverse of a symmetric positive definite ``(n, n)`` matrix (``cholesky``, then ``lower_inverse``)."""
    Li = lower_inverse(cholesky(K))
    return Li.T @ Li


def small_inverse(S):
    """Inverse of a small ``(k, k)`` quasi-definite matrix by Gauss-Jordan elimination without
    pivoting (unrolled; a quasi-definite matrix is strongly factorisable, Vanderbei 1995)."""
    k = S.shape[-1]
    M = jnp.concatenate([S, jnp.eye(k, dtype=S.dtype)], -1)
    for j in range(k):
        row = M[j] / M[j, j]
        M = (M - M[:, j : j + 1] * row[None, :]).at[j].set(row)
    return M[:, k:]


def block_factor(D, L):
    """Block LDL' of a symmetric block-tridiagonal quasi-definite matrix: ``D (T, b, b)`` the
    diagonal blocks, ``L (T, b, b)`` the blocks below them (``L[i] = K[i, i-1]``, ``L[0]``
    unused). Returns ``Si`` (the inverses of the pivot blocks) and ``G[i] = L[i] Si[i-1]``."""

    def step(si_prev, dl):
        di, li = dl
        g = li @ si_prev
        si = small_inverse(di - g @ li.T)
        return si, (si, g)

    si0 = small_inverse(D[0])
    _, (Si, G) = jax.lax.scan(step, si0, (D[1:], L[1:]))
    return jnp.concatenate([si0[None], Si], 0), jnp.concatenate([jnp.zeros_like(G[:1]), G], 0)


def block_solve(Si, G, L, r):
    """Solve ``K v = r`` (``r, v (T, b)``) with ``block_factor``'s factors."""

    def fwd(u_prev, gr):
        u = gr[1] - gr[0] @ u_prev
        return u, u

    _, u = jax.lax.scan(fwd, r[0], (G[1:], r[1:]))
    u = jnp.concatenate([r[:1], u], 0)
    v_last = Si[-1] @ u[-1]

    def bwd(v_next, sul):
        si, ui, l_next = sul
        v = si @ (ui - l_next.T @ v_next)
        return v, v

    _, v = jax.lax.scan(bwd, v_last, (Si[:-1], u[:-1], L[1:]), reverse=True)
    return jnp.concatenate([v, v_last[None]], 0)
