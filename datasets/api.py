"""pdestream.datasets: the torch side. Streams solver output into training, caches it to HDF5/Zarr,
and loads caches back; ``_bridge`` is the only module that touches JAX, and is private: code outside this package
(the CLI, surrogate) reaches the generator through the names exported here (``pde_from_config``, ``max_index``,
``param_domains``, ``sample_tensors``)."""

# name -> the module of pdestream.datasets that defines it; loaded on first use (pdestream/__init__ gives the
# namespace folder datasets/ these names: it has no __init__.py, so a checkout never shadows HuggingFace's
# `datasets` when the repository root is on sys.path).
WHERE = {
    "CachedTrajectories": "loader", "NextStep": "views", "Normalization": "normalize", "Operator": "views",
    "Reservoir": "reservoir", "ReservoirConfig": "reservoir_config", "ReservoirStream": "reservoir", "SolverOracle": "solver", "SolverStep": "solver",
    "SteadyOperator": "views", "StreamLoader": "stream", "TrajectoryStream": "stream", "VIEWS": "views",
    "Whole": "views", "WriteSummary": "cache", "collate": "views", "compute_normalization": "normalize",
    "examples": "views", "flow_vorticity": "derived", "for_sample": "views", "gather": "views", "make_view": "views",
    "max_index": "_bridge", "open_cache": "cache", "param_domains": "_bridge", "pde_from_config": "_bridge",
    "sample_tensors": "_bridge", "stream_loader": "stream", "vorticity": "derived", "write_cache": "cache",
}
__all__ = sorted(WHERE)
