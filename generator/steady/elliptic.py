"""-div(a grad u) = f on (0, L)^2 with u = 0 on the boundary: second-order finite differences and a
matrix-free Jacobi-preconditioned conjugate-gradient solve (JAX: jit- and vmap-able, any float dtype).

Discretisation. Nodes x_i = i h, i = 0..n-1, h = L / (n - 1), on both axes (the boundary nodes are in the
grid and hold u = 0; the unknowns are the (n-2)^2 interior nodes). The coefficient a is given at the nodes;
the flux through the face between two neighbouring nodes uses the *harmonic mean* of their values,
2 a_P a_E / (a_P + a_E) (the exact face coefficient of a 1D layered medium, so a jump between two cells is
not smeared), and the five-point operator at an interior node P is

    (A u)_P = [ a_e (u_P - u_E) + a_w (u_P - u_W) + a_n (u_P - u_N) + a_s (u_P - u_S) ] / h^2.

A is symmetric positive definite, so conjugate gradients apply. The code works with h^2 A and h^2 f (the
same solution, numbers of order one). Arrays are indexed [i, j] = (x_i, y_j) here; callers choose the
storage order.

Stopping rule: the relative residual ||f - A u||_2 / ||f||_2 (over interior nodes) <= tol, tested on the
recursively updated residual each iteration; each sample stops on its own (a masked while loop under vmap:
a converged sample's state is frozen), so a sample's iterates never depend on what else is in its batch.
At the end the true residual f - A u is recomputed and returned, for the caller to check.
"""

from __future__ import annotations

from typing import NamedTuple

from pdestream.generator.lazy_jax import jax, jnp


class Faces(NamedTuple):
    """Face coefficients (harmonic means of neighbouring nodal a): ax [n-1, n] between nodes (i, j) and
    (i+1, j); ay [n, n-1] between (i, j) and (i, j+1)."""

    ax: jax.Array
    ay: jax.Array


def harmonic_faces(a: jax.Array) -> Faces:
    """Face coefficients of nodal coefficient a [n, n] (> 0): Faces(ax [n-1, n], ay [n, n-1])."""
    return Faces(2 * a[:-1] * a[1:] / (a[:-1] + a[1:]), 2 * a[:, :-1] * a[:, 1:] / (a[:, :-1] + a[:, 1:]))


def apply_operator(faces: Faces, v: jax.Array) -> jax.Array:
    """h^2 A v for interior values v [n-2, n-2] (u = 0 on the boundary): [n-2, n-2]."""
    u = jnp.pad(v, 1)  # the boundary nodes hold u = 0
    fx = faces.ax * (u[1:] - u[:-1])  # a (u_E - u_P) on each x-face, [n-1, n]
    fy = faces.ay * (u[:, 1:] - u[:, :-1])  # [n, n-1]
    return -((fx[1:] - fx[:-1])[:, 1:-1] + (fy[:, 1:] - fy[:, :-1])[1:-1])


def diagonal(faces: Faces) -> jax.Array:
    """Diagonal of h^2 A (the sum of a node's four face coefficients): [n-2, n-2]."""
    return (faces.ax[1:] + faces.ax[:-1])[:, 1:-1] + (faces.ay[:, 1:] + faces.ay[:, :-1])[1:-1]


def _dot(x: jax.Array, y: jax.Array) -> jax.Array:
    return jnp.sum(x * y)


class Solution(NamedTuple):
    """u [n, n] (boundary zeros included); iterations taken; reached: whether the recursive residual met the
    tolerance; residual: the recomputed relative residual ||f - A u|| / ||f||; backward_error: the recomputed
    normwise backward error ||f - A u|| / (||A||_inf ||u|| + ||f||) (2-norms over interior nodes).

    In float32 the relative residual of even the correctly rounded solution is ~1e-4 (64^2) to ~1e-3 (128^2):
    evaluating A u differences neighbouring values of u and divides by h^2. The backward error stays near
    float32's epsilon at every size, so it is the check that a returned u solves the discrete system."""

    u: jax.Array
    iterations: jax.Array
    reached: jax.Array
    residual: jax.Array
    backward_error: jax.Array


def solve(a: jax.Array, f: jax.Array, h: float, tol: float, max_iter: int) -> Solution:
    """Solve -div(a grad u) = f, u = 0 on the boundary, for nodal a [n, n] > 0 and f [n, n] (only interior
    nodes of f are used), grid spacing h, by Jacobi-preconditioned CG from u = 0.

    Stops when the recursive relative residual reaches ``tol`` or after ``max_iter`` iterations, whichever
    comes first. Computes in the dtype of ``a``. Returns a Solution (check ``residual`` against the tolerance:
    a solve that ran out of iterations is not converged).
    """
    faces = harmonic_faces(a)
    b = (h * h) * f[1:-1, 1:-1].astype(a.dtype)
    inv_diag = 1 / diagonal(faces)
    b_norm2 = _dot(b, b)
    stop2 = (tol * tol) * b_norm2

    def not_done(state):
        k, _, _, _, _, r_norm2 = state
        return (k < max_iter) & (r_norm2 > stop2)

    def step(state):
        k, x, r, p, rz, _ = state
        ap = apply_operator(faces, p)
        alpha = rz / _dot(p, ap)
        x = x + alpha * p
        r = r - alpha * ap
        z = inv_diag * r
        rz_new = _dot(r, z)
        p = z + (rz_new / rz) * p
        return k + 1, x, r, p, rz_new, _dot(r, r)

    z0 = inv_diag * b
    state = (jnp.zeros((), jnp.int32), jnp.zeros_like(b), b, z0, _dot(b, z0), b_norm2)
    k, x, _, _, _, r_norm2 = jax.lax.while_loop(not_done, step, state)
    r = b - apply_operator(faces, x)
    r_norm = jnp.sqrt(_dot(r, r))
    a_norm = 2 * jnp.max(diagonal(faces))  # ||h^2 A||_inf: diagonal plus the off-diagonals, which sum to it
    zero = b_norm2 == 0  # f = 0: u = 0 is the exact solution (0 / 0 would read as a failed solve)
    backward = jnp.where(zero, 0.0, r_norm / (a_norm * jnp.sqrt(_dot(x, x)) + jnp.sqrt(b_norm2)))
    residual = jnp.where(zero, 0.0, r_norm / jnp.sqrt(b_norm2))
    return Solution(jnp.pad(x, 1), k, r_norm2 <= stop2, residual, backward)
