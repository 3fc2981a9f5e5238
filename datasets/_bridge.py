"""The one place where the torch side meets JAX.

- ``configure_jax()`` sets per-process JAX options before JAX starts: no GPU preallocation (torch shares
  the device), and a persistent compilation cache in a private per-user directory so a second process
  (a DataLoader worker, a resumed run) does not recompile from scratch.
- ``to_torch(x)`` hands a JAX array to torch through DLPack: zero-copy on CPU and on a shared GPU.
  The tensor shares JAX's buffer: never modify it in place (clone first).
- ``trajectory_tensors(traj)`` converts a generator.Trajectory to torch tensors; ``sample_tensors`` and
  ``sample_numpy`` solve samples straight to torch / numpy; ``resolve_pde``, ``pde_from_config`` and
  ``max_index`` give the rest of datasets/ what it needs of generator without importing it (nor JAX).
"""

from __future__ import annotations

import functools
import json
import os
import time
from pathlib import Path

CACHE_ENV = "PDESTREAM_JAX_CACHE"


def jax_cache_dir() -> Path:
    """Private directory of JAX's persistent compilation cache (``$PDESTREAM_JAX_CACHE`` overrides; set to the empty
    string, no persistent cache is used)."""
    default = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "pdestream" / "jax"
    return Path(os.environ.get(CACHE_ENV, default))


def configure_jax() -> None:
    """Set JAX's process options; call before JAX computes anything (safe to call repeatedly)."""
    # Must be in the environment before the JAX backend starts: 75% GPU preallocation would starve torch.
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    from pdestream import generator

    if os.environ.get(CACHE_ENV) == "":  # set and empty: no persistent compilation cache (the test suite)
        return
    try:
        generator.enable_compilation_cache(jax_cache_dir())
    except OSError:
        pass  # a read-only home only costs recompilation (an unsafe directory is refused with a warning there)


def to_torch(x):
    """JAX array -> torch.Tensor on the same device, sharing memory (DLPack)."""
    import torch

    return torch.from_dlpack(x)


def sample_channels(pde) -> tuple[str, ...]:
    """The one statement of a sample's layout on the torch/numpy side: the names along its channel axis.

    A time-dependent PDE's sample is u [T, C, *space] over PDE.FIELDS. A steady PDE's (``PDE.STEADY``: no time
    axis) is one array [C_in + C, *space] over PDE.INPUTS + PDE.FIELDS: its random input fields (darcy2d's
    coefficient a), then its solution, so one tensor carries the operator's input and output through the
    stream, the reservoir and the cache loader alike. A cache stores each channel as its own variable."""
    return (*pde.INPUTS, *pde.FIELDS)


def _joined(traj, concat, convert):
    """traj.u, with a steady sample's input fields put in front along the channel axis (``sample_channels``)."""
    u = convert(traj.u)
    return u if traj.inputs is None else concat([convert(traj.inputs), u], 1)


def trajectory_tensors(traj) -> dict:
    """generator.Trajectory -> {"u": [B, T, C, *space] (steady PDEs: [B, C_in + C, *space], see
    ``sample_channels``), "t": [T], "params": [B, P], "index": [B]} (torch), and one key per output the PDE
    declares (``Problem.OUTPUTS``: [B, *dims], e.g. karman2d's "drag" [B, T], "sdf" [B, nx, ny], "developed" [B]).

    Parameter columns follow the PDE's PARAMS order; "param_names" lists them.
    """
    import numpy as np
    import torch

    names = list(traj.pde.PARAMS)
    u = _joined(traj, torch.cat, to_torch)
    if names:
        params = torch.stack([to_torch(traj.params[n]) for n in names], dim=1)
    else:
        params = torch.zeros((u.shape[0], 0), dtype=torch.float32)
    return {
        "u": u,
        "t": torch.from_numpy(np.asarray(traj.t)),
        "params": params,
        "index": torch.from_numpy(np.asarray(traj.indices, dtype=np.int64)),
        "param_names": names,
        **{k: torch.from_numpy(np.array(v)) for k, v in traj.outputs.items()},
    }


def configure_worker(worker_id: int = 0) -> None:
    """``worker_init_fn`` for DataLoader worker processes: JAX on the CPU (the GPU is torch's), then
    ``configure_jax``. Works because unpickling the dataset does not start a JAX backend."""
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    import jax

    jax.config.update("jax_platforms", os.environ["JAX_PLATFORMS"])
    configure_jax()


def jax_provenance() -> dict:
    """What decides the bits of a sample besides (config, seed, index): JAX's version and PRNG mode, and the
    revision of pdestream's numerics (``generator.NUMERICS``)."""
    import jax

    from pdestream import generator

    return {"jax_version": jax.__version__, "jax_threefry_partitionable": int(jax.config.jax_threefry_partitionable),
            "pdestream_numerics": generator.NUMERICS}


def progress_key(kind: str, pde) -> str:
    """The key under which a run's measured times are recorded (``datasets.timings``): what it runs, the entry's
    config hash and JAX's backend (a GPU's times are not a CPU's). Not the block: solves compile per fixed chunk,
    so another --n (and so another default block) starts from the same record."""
    import jax

    return f"{kind} {pde.NAME} {pde.config_hash()} {jax.default_backend()}"


def typical_times(pde) -> dict | None:
    """The entry's declared times of a default run (``TYPICAL_TIMES``: {"startup_s", "unit_s"} measured on 2 CPU
    cores), for a progress line's first estimate on a machine with no record yet; None when it declares none, runs
    on another backend, or ``pde`` is not at its defaults (another grid compiles and solves at another cost)."""
    import jax

    typical = getattr(pde, "TYPICAL_TIMES", None)
    if not typical or jax.default_backend() != "cpu":
        return None
    try:
        default = type(pde)().config_hash()
    except Exception:  # a plug-in without defaults for every argument: no typical run to speak of
        return None
    return {**typical, "basis": "typical of its defaults on 2 CPU cores"} if default == pde.config_hash() else None


def resolve_pde(pde):
    """A generator PDE from a PDE object or a catalog name."""
    from pdestream import generator

    if isinstance(pde, str):
        return generator.get_pde(pde)
    if not isinstance(pde, generator.ProblemBase):
        raise ValueError(f"pde must be a generator PDE or a catalog name ({', '.join(generator.PDES)}), got {pde!r}")
    return pde


def sample_tensors(pde, indices, seed: int = 0, on_blowup: str = "raise", params: dict | None = None) -> dict:
    """``trajectory_tensors(generator.sample(pde, indices, seed, on_blowup, params=params))``; NaN/Inf raises
    BlowUpError (on_blowup="skip": such samples are left out, "index" says which are there). params: optional
    explicit values {name: [B]} (the IC still comes from (seed, index))."""
    from pdestream import generator

    traj = generator.sample(pde, indices, seed, on_blowup=on_blowup, params=params)
    warn_skipped(traj.skipped)
    return trajectory_tensors(traj)


def cancel_solves_on(event) -> None:
    """Solves in the calling thread stop at their next bounded call (raising generator.sampler.Cancelled) once
    the threading.Event ``event`` is set: how a producer thread learns that its consumer has gone."""
    from pdestream.generator.sampler import cancel_on

    cancel_on(event)


def sample_numpy(pde, indices, seed: int = 0, on_blowup: str = "raise", params: dict | None = None,
                 with_outputs: bool = False):
    """``generator.sample`` as numpy: (u float32 [B, T, C, *space] (steady PDEs: [B, C_in + C, *space], see
    ``sample_channels``), {param: float32 [B]}, redraws int64 [B]), and with ``with_outputs`` the problem's
    per-sample outputs {name: [B, *dims]} (``Problem.OUTPUTS``) as a fourth item."""
    import numpy as np

    from pdestream import generator

    traj = generator.sample(pde, indices, seed, on_blowup=on_blowup, params=params)
    u = _joined(traj, np.concatenate, np.asarray)
    out = (u, {k: np.asarray(v) for k, v in traj.params.items()}, np.asarray(traj.redraws))
    return (*out, {k: np.asarray(v) for k, v in traj.outputs.items()}) if with_outputs else out


def solve_job(config: dict, seed: int, indices, params: dict | None = None, on_blowup: str = "raise",
              on_device: bool = False) -> dict:
    """A producer's job (thread, spawned process or Dask worker): solve samples ``indices`` of the PDE of
    ``config`` under ``seed`` with optional explicit ``params`` {name: [B]}. Returns
    {"u": float32 [B, T, C, *space], "params": float32 [B, P] (PARAMS order), "index": int64 [B], "skipped": lines,
    "seconds": the job's own wall time, where it ran (the reservoir's pacing reads it)},
    all numpy, or with ``on_device`` (a job run in the consumer's process) "u" as a torch tensor on JAX's device
    that shares JAX's finished buffer (DLPack: no host round trip; read it, never write it). Same values either
    way. With on_blowup="skip" the samples that failed are left out (B rows fewer; "index" says which are there)
    and "skipped" lists one line per sample left out."""
    import jax
    import numpy as np

    from pdestream import generator

    t0 = time.perf_counter()
    configure_jax()
    pde = _pde_of(json.dumps(config, sort_keys=True))
    params = dict(params or {})
    latent = params.pop(LATENT, None)
    traj = generator.sample(pde, np.asarray(indices, np.int64), seed, on_blowup=on_blowup, params=params or None,
                            latent=latent)
    if on_device and isinstance(traj.u, jax.Array):  # (an external solver's result is numpy already)
        import torch

        jax.block_until_ready((traj.u, traj.inputs))  # done before torch reads it on its own stream
        u = _joined(traj, torch.cat, to_torch)
    else:
        u = _joined(traj, np.concatenate, np.asarray)
    cols = [np.asarray(traj.params[n]) for n in pde.PARAMS]
    out = {"u": u, "params": np.stack(cols, 1) if cols else np.zeros((len(u), 0), np.float32),
           "index": np.asarray(traj.indices, np.int64), "skipped": list(traj.skipped),
           "seconds": time.perf_counter() - t0}
    if latent is not None:  # the latents given, for the rows kept (on_blowup="skip" may leave some out)
        first = {}  # index -> its row (a padded job repeats rows: the same index, the same latent)
        for row, i in enumerate(np.asarray(indices, np.int64).tolist()):
            first.setdefault(i, row)
        out["latent"] = np.asarray(latent, np.float32)[[first[i] for i in out["index"].tolist()]]
    return out


@functools.lru_cache(maxsize=16)
def _pde_of(config_json: str):
    return pde_from_config(json.loads(config_json))


# params' key for a job's IC latents [B, L] (a joint proposal's; datasets.proposal.LATENT)
LATENT = "ic:latent"


def latent_size(pde) -> int:
    """L: the steerable coordinates of the PDE's IC (generator.ics.LatentIC), 0: none."""
    return int(pde.latent_size()) if hasattr(pde, "latent_size") else 0


def latent_prior(pde) -> tuple:
    """The IC latent's law ("normal" | "uniform", a [L], b [L]) (``LatentIC.latent_prior``)."""
    return pde.latent_prior()


def param_domains(pde) -> dict:
    """{name: (kind, low, high, options)} of the PDE's parameters in PARAMS order, as plain values:
    kind is "fixed", "uniform", "loguniform" or "choice"; options is the tuple of a choice, else ()."""
    out = {}
    for name, dom in pde.param_domains.items():
        kind = type(dom).__name__.lower()
        low, high = dom.bounds
        out[name] = (kind, float(low), float(high), tuple(getattr(dom, "options", ())))
    return out


def warn_skipped(lines) -> None:
    """Each line of a solve's "skipped" list as a generator.sampler.SkippedSamples warning."""
    from pdestream.generator.sampler import warn_skipped as warn

    warn(lines)


def check_on_blowup(on_blowup) -> str:
    """``on_blowup`` if it is a policy (raise / redraw / skip), else a one-line ValueError."""
    from pdestream.generator.sampler import check_on_blowup as check

    return check(on_blowup)


def check_params(pde, params: dict, batch: int) -> None:
    """ValueError (one line) unless ``params`` {name: [batch]} are parameters of ``pde`` inside their domains."""
    from pdestream.generator.sampler import explicit_params

    explicit_params(pde, params, batch)


def pde_from_config(config: dict):
    """``generator.from_config``: the PDE of a stored ``PDE.config()`` dict."""
    from pdestream import generator

    return generator.from_config(config)


def max_index() -> int:
    """The largest sample index the generator accepts (indices are 0..max_index())."""
    from pdestream.generator.sampler import MAX_INDEX

    return MAX_INDEX


# --- the solver as a function of torch states (generator.interactive) ----------------------------------------

def solver_pde(pde):
    """A generator PDE from a catalog name, a generator PDE or a ``PDE.config()`` dict."""
    if isinstance(pde, dict):
        return pde_from_config(pde)
    return resolve_pde(pde)


def _jax_device(device):
    """The JAX device for a torch device: the CPU, or the GPU of the same index (one line if JAX has none)."""
    import jax

    if device.type == "cpu":
        return jax.devices("cpu")[0]
    if device.type == "cuda":
        try:
            gpus = jax.devices("gpu")
        except RuntimeError:
            gpus = []
        index = device.index or 0
        match = [d for d in gpus if d.id == index]
        if match:
            return match[0]
        have = ", ".join(sorted({d.platform for d in jax.devices()}))
        raise ValueError(f"state is on {device} but JAX has no such device (JAX devices: {have}); install JAX's "
                         "CUDA build (pip install -U 'jax[cuda12]') or pass CPU tensors")
    raise ValueError(f"state is on {device}; allowed: cpu, or cuda with JAX's CUDA build")


def to_jax(t, device):
    """Contiguous torch tensor -> JAX array on JAX device ``device``: a copy through numpy on the CPU,
    DLPack (zero-copy, shares the tensor's memory: read-only use) on a GPU."""
    import jax
    import torch

    t = t.detach().contiguous()
    if t.device.type == "cpu":
        return jax.device_put(t.numpy(), device)
    # torch may still be writing t on its own stream, and JAX reads on another one: wait for torch's first
    torch.cuda.current_stream(t.device).synchronize()
    return jax.dlpack.from_dlpack(t)


def _solver_inputs(pde, u, params, frames: int):
    """Checks a torch state [B, C, *space] and params [B, P] against ``pde`` (one-line ValueError naming the bad
    value and what is allowed); returns (u, {name: [B]}) as JAX arrays on the JAX twin of u's device."""
    import jax
    import numpy as np
    import torch

    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
        raise ValueError(f"{pde.NAME}: frames={frames!r} not allowed: need an integer >= 1")
    grid, names = pde.grid, list(pde.PARAMS)
    want = f"[B, {len(pde.FIELDS)}, {', '.join(map(str, grid.shape))}]"
    if not isinstance(u, torch.Tensor):
        raise ValueError(f"{pde.NAME}: state must be a torch.Tensor {want}, got {type(u).__name__}")
    if u.ndim != 2 + grid.ndim or tuple(u.shape[1:]) != (len(pde.FIELDS), *grid.shape) or u.shape[0] < 1:
        raise ValueError(f"{pde.NAME}: state has shape {list(u.shape)}; expected {want} (fields "
                         f"{', '.join(pde.FIELDS)}; grid n={grid.n})")
    wide = u.dtype == torch.float64 and jax.config.jax_enable_x64
    if u.dtype != torch.float32 and not wide:
        raise ValueError(f"{pde.NAME}: state dtype {u.dtype} not allowed: float32 (float64 only with "
                         "jax_enable_x64 on)")
    batch = u.shape[0]
    if params is None and not names:
        params = u.new_zeros((batch, 0))
    if not isinstance(params, torch.Tensor) or tuple(params.shape) != (batch, len(names)):
        shape = list(params.shape) if isinstance(params, torch.Tensor) else type(params).__name__
        raise ValueError(f"{pde.NAME}: params {shape} not allowed: need a tensor [{batch}, {len(names)}] with "
                         f"columns {names}")
    if params.device != u.device:
        raise ValueError(f"{pde.NAME}: params are on {params.device} but the state is on {u.device}; put both on "
                         "one device")
    device = _jax_device(u.device)
    if not bool(torch.isfinite(u).all()):
        bad = torch.nonzero(~torch.isfinite(u.reshape(batch, -1)).all(1)).flatten()[:10].tolist()
        raise ValueError(f"{pde.NAME}: state has NaN/Inf in batch entries {bad}; allowed: finite values")
    host = params.detach().cpu().double().numpy()
    check_params(pde, {n: host[:, j] for j, n in enumerate(names)}, batch)
    dtype = np.float64 if wide else np.float32
    return to_jax(u, device), {n: jax.device_put(host[:, j].astype(dtype), device) for j, n in enumerate(names)}


def _blown_up(pde, finite, frames: int) -> None:
    import numpy as np

    from pdestream import generator

    bad = np.flatnonzero(~np.asarray(finite))
    if bad.size:
        raise generator.BlowUpError(
            f"{pde.NAME}: the solver blew up (NaN/Inf) advancing batch entries {bad[:10].tolist()} by {frames} "
            f"frame(s) with step {pde.step_dt:.4g}: those states or parameters are outside what the step resolves")


def refuse_refined(pde) -> None:
    """One-line ValueError if ``pde`` has ``refine`` above 1 (the interactive modes step states on their own grid)."""
    from pdestream.generator.spectral import interactive

    interactive.refuse_refined(pde)


def solver_advance(pde, u, params, frames: int = 1):
    """torch u [B, C, *space], params [B, P] (PARAMS order) -> u advanced ``frames`` frames, torch, on u's device.

    BlowUpError if a result is NaN/Inf. The output may share memory with JAX's result buffer (not kept by JAX).
    """
    from pdestream.generator.spectral import interactive

    u_j, p_j = _solver_inputs(pde, u, params, frames)
    out, finite = interactive.advance(pde, u_j, p_j, int(frames))
    _blown_up(pde, finite, frames)
    return to_torch(out)


def solver_advance_vjp(pde, u, params, frames: int = 1, wrt_params: bool = True):
    """``solver_advance`` and its backward: (out torch [B, C, *space], backward).

    backward(g torch [B, C, *space]) -> (g_u [B, C, *space], g_params [B, P] or None), torch on u's device.
    """
    import jax
    import torch

    from pdestream.generator.spectral import interactive

    u_j, p_j = _solver_inputs(pde, u, params, frames)
    out, finite, vjp = interactive.advance_vjp(pde, u_j, p_j, int(frames), wrt_params)
    _blown_up(pde, finite, frames)
    device, names = u_j.devices().pop(), list(pde.PARAMS)

    def backward(g):
        g_u, g_p = jax.block_until_ready(vjp(to_jax(g, device)))  # finished before torch reads the buffers
        if g_p is None:
            return to_torch(g_u), None
        cols = [to_torch(g_p[n]) for n in names]
        return to_torch(g_u), (torch.stack(cols, 1) if cols else torch.zeros_like(params))

    return to_torch(out), backward
