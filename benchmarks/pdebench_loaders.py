"""PDEBench's own per-seed loaders (``FNODatasetMult``, ``UNetDatasetMult``) on `pdestream export --to pdebench`
files of the three sets PDEBench ships per seed: each loader's first item against the cache it came from.

    python -m benchmarks.pdebench_loaders --pdebench PDEBENCH_CHECKOUT [--out /tmp/pdebench_loaders]

PDEBENCH_CHECKOUT: a clone of github.com/pdebench/PDEBench (its ``pdebench/models/{fno,unet}/utils.py`` are loaded
from there as they are; torch and h5py are all they import). Tiny caches (3 samples, 3 frames) are generated into
--out first.
"""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

import numpy as np

CASES = {  # entry: its tiny settings
    "diffusion_sorption1d": {"n": "16", "n_frames": "3", "t_end": "1"},
    "diffusion_reaction2d": {"n": "32", "n_frames": "3", "t_end": "0.1"},
    "shallow_water2d": {"n": "16", "n_frames": "3", "t_end": "0.1"},
}


def _module(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.pdebench_loaders", description=__doc__.splitlines()[0])
    ap.add_argument("--pdebench", required=True, help="a clone of PDEBench's repository")
    ap.add_argument("--out", default="/tmp/pdebench_loaders")
    a = ap.parse_args(argv)
    from pdestream.datasets import schema
    from pdestream.datasets.cache import open_cache
    from pdestream.datasets.export import export_cache
    from pdestream.datasets.generate import GenerateConfig, generate
    from pdestream.datasets.pdebench_seeds import PER_SEED_CHANNELS

    repo, out = Path(a.pdebench), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    loaders = {"FNODatasetMult": _module(repo / "pdebench/models/fno/utils.py", "pdebench_fno_utils"),
               "UNetDatasetMult": _module(repo / "pdebench/models/unet/utils.py", "pdebench_unet_utils")}
    print("| entry | loader | items | yy [x(, y), t, C] | grid | every channel equals the cache's field |")
    print("| --- | --- | --- | --- | --- | --- |")
    for entry, settings in CASES.items():
        cache, export = out / f"{entry}.h5", out / f"{entry}_pdebench.h5"
        if not cache.exists():
            generate(GenerateConfig(pde=entry, settings=settings, n=3, out=str(cache)))
        export_cache(cache, "pdebench", export, overwrite=export.exists())
        with open_cache(cache) as ds:
            ndim = schema.space_ndim(ds[PER_SEED_CHANNELS[entry][0]].dims)
            fields = {f: schema.from_disk(np.asarray(ds[f].values, np.float32), ndim) for f in PER_SEED_CHANNELS[entry]}
        for name, module in loaders.items():
            # their loaders open SAVED_FOLDER + FILENAME + ".h5"; test_ratio 0: every sample is a training item
            data = getattr(module, name)(export.stem, initial_step=2, saved_folder=f"{out}/", test_ratio=0.0)
            item = data[0]
            yy = item[1].numpy()  # [x(, y), t, C]
            same = all(np.array_equal(np.moveaxis(yy[..., c], -1, 0), fields[f][0])
                       for c, f in enumerate(PER_SEED_CHANNELS[entry]))
            grid = tuple(item[2].shape) if len(item) > 2 else "(none)"
            print(f"| {entry} | {name} | {len(data)} | {tuple(yy.shape)} | {grid} | {same} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
