"""(problem config, seed, index) -> sample: keys, explicit parameters, the blow-up policy, and ``Trajectory``.

Sample i uses the key ``fold_in(key(seed), i)``; the problem splits it into a parameter key and an IC (or
input-field) key and solves it (``Problem.run_keys``: the spectral family's rollouts are generator.rollout's,
the steady family's solves its own), so a sample does not depend on which other samples share its batch. A
redrawn sample (after a blow-up) uses ``fold_in(fold_in(key(seed), i), attempt)``. This module reads problems
only through the protocol (generator.problem); nothing below it imports it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Mapping, Sequence

import numpy as np

from pdestream.generator.lazy_jax import jax, jit, jnp

from .catalog import get_pde
from .dispatch import Cancelled, cancel_on
from .problem import Problem, draw_params

PDE = Problem  # the name the signatures below have always used
__all__ = ["BlowUpError", "Cancelled", "MAX_INDEX", "Trajectory", "cancel_on", "draw_params", "explicit_latent", "explicit_params",
           "sample", "sample_keys", "solve"]

OnBlowup = Literal["raise", "redraw", "skip"]
ON_BLOWUP = ("raise", "redraw", "skip")
MAX_INDEX = 2**32 - 1


class BlowUpError(ValueError):
    """A solve produced NaN or Inf (or an external solver failed); names the sample indices, their parameters
    and, where the problem gives one, each failure's cause."""


class SkippedSamples(UserWarning):
    """on_blowup="skip" left samples out: one line per sample, naming its index, parameters and cause."""


def check_on_blowup(on_blowup) -> str:
    """``on_blowup`` if it is a policy (raise / redraw / skip), else a one-line ValueError."""
    if on_blowup not in ON_BLOWUP:
        raise ValueError(f"on_blowup={on_blowup!r} not allowed; allowed: {', '.join(map(repr, ON_BLOWUP))}")
    return on_blowup


@dataclass
class Trajectory:
    """A batch of solutions.

    u: float32 [B, T, C, *space] (jax array), or [B, C, *space] for a steady PDE (``pde.STEADY``: no time
    axis, t is empty); t: float32 [T]; params: {name: float32 [B]}; indices: int64 [B] global sample indices
    (None for ``solve``); redraws: int [B] blow-up redraws used; inputs: float32 [B, C_in, *space], the
    random input fields ``pde.INPUTS`` of a steady PDE (darcy2d's coefficient a), else None; outputs:
    {name: [B, *dims]}, the problem's per-sample variables ``pde.OUTPUTS`` (forces, distances, flags) of these
    samples ({} where it declares none).
    """

    u: jax.Array
    t: np.ndarray
    params: dict[str, jax.Array]
    pde: PDE
    indices: np.ndarray | None = None
    redraws: np.ndarray | None = field(default=None)
    inputs: jax.Array | None = None
    skipped: tuple[str, ...] = ()  # on_blowup="skip": one line per sample left out (index, params, cause)
    outputs: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.u.shape[0])


@jit(static_argnums=2)
def _fold_keys(base: jax.Array, idx: jax.Array, attempt: int) -> jax.Array:
    # jitted: traced eagerly, these two vmaps cost ~3 ms per sample() call (integer hashing: same bits)
    keys = jax.vmap(lambda i: jax.random.fold_in(base, i))(idx)
    if attempt:
        keys = jax.vmap(lambda k: jax.random.fold_in(k, attempt))(keys)
    return keys


def sample_keys(seed: int, indices: np.ndarray, attempt: int = 0) -> jax.Array:
    """Keys fold_in(key(seed), i) (and fold_in(., attempt) for attempt > 0), one per index: [B]."""
    return _fold_keys(jax.random.key(seed), jnp.asarray(indices, jnp.uint32), attempt)


def _check_indices(indices: Sequence[int] | np.ndarray | int) -> np.ndarray:
    idx = np.atleast_1d(np.asarray(indices))
    if idx.ndim != 1 or idx.size == 0 or not np.issubdtype(idx.dtype, np.integer):
        raise ValueError(f"indices must be a non-empty 1D sequence of integers, got {indices!r}")
    if idx.min() < 0 or idx.max() > MAX_INDEX:
        raise ValueError(f"sample indices must be in [0, {MAX_INDEX}], got min {idx.min()} max {idx.max()}")
    return idx.astype(np.int64)


def explicit_params(pde: PDE, params: Mapping[str, Sequence[float] | float] | None, batch: int):
    """Caller's parameter values -> (explicit float32 [B, P], given bool [B, P]) in PDE.PARAMS order.

    ``params`` maps some or all of the PDE's parameters to a scalar or [B] values; each value must lie in its
    domain (ValueError naming the parameter, the value and the domain otherwise). Parameters left out are drawn.
    """
    names = list(pde.PARAMS)
    explicit = np.zeros((batch, len(names)), np.float32)
    given = np.zeros((batch, len(names)), bool)
    if not params:
        return explicit, given
    unknown = sorted(set(params) - set(names))
    if unknown:
        raise ValueError(f"{pde.NAME}: unknown parameter(s) {unknown}; allowed: {names}")
    for name, values in params.items():
        j = names.index(name)
        v = np.asarray(values, np.float64)
        if v.ndim > 1 or (v.ndim == 1 and v.shape[0] != batch):
            raise ValueError(f"{pde.NAME}: params[{name!r}] has shape {v.shape}; expected a scalar or [{batch}]")
        v = np.broadcast_to(v, (batch,))
        domain = pde.param_domains[name]
        bad = [x for x in v if not (np.isfinite(x) and domain.contains(x))]
        if bad:
            raise ValueError(f"{pde.NAME}: {name}={bad[0]:.6g} not allowed: outside its domain {domain}")
        explicit[:, j], given[:, j] = v.astype(np.float32), True
    return explicit, given


def explicit_latent(pde: PDE, latent, batch: int):
    """Caller's IC latents -> (float32 [B, L], given bool [B]), or None when ``latent`` is None.

    ``latent``: [L] (every sample) or [B, L]; a row of all NaN is "the key's own" (not given). A problem whose IC
    has no latent (``latent_size() == 0``), a wrong shape or a partly non-finite row is refused in one line.
    """
    if latent is None:
        return None
    size = pde.latent_size() if hasattr(pde, "latent_size") else 0
    if size == 0:
        raise ValueError(f"{pde.NAME}: its ic ({getattr(pde, 'ic', None)}) has no latent coordinates; a latent cannot "
                         "be given (leave latent out)")
    z = np.asarray(latent, np.float64)
    if z.ndim == 1:
        z = np.broadcast_to(z, (batch, z.shape[0]))
    if z.ndim != 2 or z.shape != (batch, size):
        raise ValueError(f"{pde.NAME}: latent has shape {np.shape(latent)}; expected [{size}] or [{batch}, {size}]")
    missing = np.isnan(z).all(axis=1)
    bad = ~missing & ~np.isfinite(z).all(axis=1)
    if bad.any():
        raise ValueError(f"{pde.NAME}: latent row {int(np.flatnonzero(bad)[0])} is not finite; allowed: finite "
                         "numbers, or a row of all NaN (the key's own latent)")
    return np.where(missing[:, None], 0.0, z).astype(np.float32), ~missing


def sample(
    pde: PDE | str,
    indices: Sequence[int] | np.ndarray | int,
    seed: int = 0,
    on_blowup: OnBlowup = "raise",
    max_redraws: int = 3,
    params: Mapping[str, Sequence[float] | float] | None = None,
    latent=None,
) -> Trajectory:
    """Solve samples ``indices`` of ``pde`` under ``seed``: a Trajectory with u [B, T, C, *space].

    params: optional explicit values {name: scalar or [B]} for some or all parameters (each inside its
    domain); the initial condition still comes from the key of (seed, index), so sample identity is
    (config, seed, index, params), and a sample given its drawn values is bit-identical to the drawn one.
    latent: optional IC latent coordinates [L] or [B, L] (``pde.latent_size()``; a row of NaN: the key's own):
    the IC's steerable coordinates (generator.ics.LatentIC), the rest of the IC still from the key; identity is
    then (config, seed, index, params, latent), and a sample given its key's latent is bit-identical to it.
    on_blowup="raise": a NaN/Inf trajectory raises BlowUpError naming the indices and parameters.
    on_blowup="redraw": such a sample is redrawn with attempt keys 1..max_redraws (deterministic per
    index; explicit parameters are kept, only the drawn ones and the IC change); ``Trajectory.redraws``
    counts them; still failing after max_redraws raises.
    on_blowup="skip": such a sample is left out (the Trajectory has fewer rows; ``indices`` says which are
    there) and ``Trajectory.skipped`` holds one line per sample left out (the stream and the reservoir issue
    each as a SkippedSamples warning: ``warn_skipped``).
    A problem with per-sample causes (an external solver: raised, timed out, crashed, wrong shape, NaN) names
    each failure's cause (``failure_causes``).
    """
    pde = get_pde(pde) if isinstance(pde, str) else pde
    check_on_blowup(on_blowup)
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**63:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")  # True is an int to Python, not a seed
    idx = _check_indices(indices)
    explicit, given = explicit_params(pde, params, len(idx))
    lat = explicit_latent(pde, latent, len(idx))
    extra = {} if lat is None else {"latent": lat}  # only a latent-taking family is handed one
    # each kind of PDE solves its samples its own way (time-dependent: ETDRK4 rollouts; steady: PCG)
    keys = sample_keys(int(seed), idx)
    u, params, finite, inputs = pde.run_keys(keys, explicit, given, **extra)
    causes = _causes(pde, len(idx))
    redraws = np.zeros(len(idx), np.int64)
    attempt = 0
    bad = np.flatnonzero(~np.asarray(finite))
    while bad.size and on_blowup == "redraw" and attempt < max_redraws:
        attempt += 1
        # rerun the full batch shape (failed keys padded by repetition) so no new compile is needed
        retry = np.resize(bad, len(idx))
        again = {} if lat is None else {"latent": (lat[0][retry], lat[1][retry])}  # a given latent is kept
        keys2 = sample_keys(int(seed), idx[retry], attempt)
        u2, p2, f2, in2 = pde.run_keys(keys2, explicit[retry], given[retry], **again)
        causes[bad] = _causes(pde, len(idx))[: bad.size]
        sel = jnp.asarray(bad)
        u = u.at[sel].set(u2[: bad.size])
        keys = keys.at[sel].set(keys2[: bad.size])
        inputs = None if inputs is None else inputs.at[sel].set(in2[: bad.size])
        params = {k: v.at[sel].set(p2[k][: bad.size]) for k, v in params.items()}
        redraws[bad] = attempt
        bad = bad[~np.asarray(f2[: bad.size])]
    if bad.size and on_blowup != "skip":
        detail = "; ".join(_failed(pde.NAME, idx[b], causes[b], params, b) for b in bad[:5])
        hint = "" if on_blowup == "redraw" else (" (on_blowup='redraw' draws replacements; a stream or reservoir may also "
                                                     "'skip' them, a cache may not: it holds every index)")
        what, remedy = pde.failure()
        raise BlowUpError(f"{pde.NAME}: {bad.size} of {len(idx)} {what}: {detail}{hint}; {remedy}")
    # the per-sample outputs of the final samples (after redraws): a pure function of each sample's u and params
    # (and of its key: geometry drawn from it that u does not hold, e.g. channel2d's sharp bodies)
    outputs = pde.outputs(u, params, keys) if getattr(pde, "OUTPUTS", None) else {}
    if bad.size:
        return _skipping(pde, u, params, idx, redraws, inputs, bad, causes, outputs)
    return Trajectory(u=u, t=pde.times(), params=params, pde=pde, indices=idx, redraws=redraws, inputs=inputs,
                      outputs=outputs)


def warn_skipped(lines) -> None:
    """Issue each line of ``Trajectory.skipped`` as a SkippedSamples warning (nothing left out silently)."""
    import warnings

    for line in lines:
        warnings.warn(line, SkippedSamples, stacklevel=2)


def _causes(pde: PDE, batch: int) -> np.ndarray:
    """The per-sample causes of the last run_keys (object [batch], '' where none is given)."""
    out = np.full(batch, "", object)
    given = pde.failure_causes()
    out[: len(given)] = given[:batch]
    return out


def _failed(name: str, index: int, cause: str, params: dict, b: int) -> str:
    """One failed sample in words: its index and its cause, or (no cause given) its parameters."""
    if cause:
        return f"index {index}: {cause}"
    return f"index {index}: " + ", ".join(f"{k}={float(v[b]):.4g}" for k, v in params.items())


def _skipping(pde, u, params, idx, redraws, inputs, bad, causes, outputs) -> Trajectory:
    """on_blowup="skip": the Trajectory of the samples that did not fail, with one line per failure."""
    lines = tuple(f"{pde.NAME}: skipped sample {_failed(pde.NAME, idx[b], causes[b], params, b)}" for b in bad)
    keep = np.setdiff1d(np.arange(len(idx)), bad)
    sel = jnp.asarray(keep)
    return Trajectory(u=u[sel], t=pde.times(), params={k: v[sel] for k, v in params.items()}, pde=pde,
                      indices=idx[keep], redraws=redraws[keep], inputs=None if inputs is None else inputs[sel],
                      skipped=lines, outputs={k: v[sel] for k, v in outputs.items()})


def solve(pde: PDE | str, u0, params: Mapping[str, float | Sequence[float]]) -> Trajectory:
    """Solve from a caller's initial condition.

    u0: [C, *space] or [B, C, *space] (C may be omitted for one-field PDEs when unbatched 1D/2D arrays
    match the grid); params: {name: scalar or [B]} for every parameter of the PDE. Returns u [B, T, C, *space].
    On a grid with walls u0 is read in the walls' basis: minus the lifting of its boundary values, projected onto
    the sine (Dirichlet) / cosine (Neumann) series at the cell centres and dealiased like any state, so frame 0 is
    that projection (which holds the walls) rather than u0 itself.
    """
    pde = get_pde(pde) if isinstance(pde, str) else pde
    if pde.STEADY:
        raise ValueError(f"{pde.NAME} is steady: it has no initial condition to evolve; use sample(pde, indices, seed, "
                         "params=...) (its input field comes from the key of each index)")
    if not callable(getattr(pde, "evolve", None)):  # the flows (AttributeError before)
        raise ValueError(f"{pde.NAME}: its solver does not start from a caller's state (its samples start from the "
                         "state its IC draws); allowed: sample(pde, indices, seed, params=...)")
    grid, n_fields = pde.grid, len(pde.FIELDS)
    u0 = jnp.asarray(u0, jnp.float32)
    if u0.shape == grid.shape:
        u0 = u0[None]
    if u0.shape == (n_fields, *grid.shape):
        u0 = u0[None]
    if u0.ndim != 2 + grid.ndim or u0.shape[1:] != (n_fields, *grid.shape):
        raise ValueError(
            f"{pde.NAME}: u0 has shape {tuple(u0.shape)}; expected [B, {n_fields}, {', '.join(map(str, grid.shape))}]"
        )
    missing = set(pde.PARAMS) - set(params)
    extra = set(params) - set(pde.PARAMS)
    if missing or extra:
        raise ValueError(f"{pde.NAME}: params must be exactly {sorted(pde.PARAMS)}; missing {sorted(missing)}, unknown {sorted(extra)}")
    batch = u0.shape[0]
    p = {k: jnp.broadcast_to(jnp.asarray(v, jnp.float32), (batch,)) for k, v in params.items()}
    for name, spec in pde.PARAMS.items():
        if spec.positive and not bool(jnp.all(p[name] > 0)):
            raise ValueError(f"{pde.NAME}: {name}={np.asarray(p[name])} not allowed: {spec.description} must be > 0")
    u, finite = pde.evolve(u0, p)  # the family's rollout in bounded calls (a Ctrl-C stops it within one)
    bad = np.flatnonzero(~np.asarray(finite))
    if bad.size:  # the family's words for a failure and each failed entry's cause (euler1d: which and when)
        what, avoid = pde.failure()
        causes = _causes(pde, batch)
        entries = "; ".join(f"{b}: {causes[b]}" if causes[b] else str(b) for b in bad[:10].tolist())
        raise BlowUpError(f"{pde.NAME}: solve: {what} for batch entries {entries}; {avoid}")
    return Trajectory(u=u, t=pde.times(), params=p, pde=pde)
