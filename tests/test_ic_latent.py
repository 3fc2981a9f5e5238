"""IC latents (generator.ics.LatentIC): the latent a key draws gives back that key's IC bit for bit, for every IC kind;
a sample given an explicit latent is a pure function of (config, seed, index, latent): alone == in a batch, and given
its key's own latent == the drawn sample. Small grids: the whole file is a few seconds."""

import jax
import numpy as np
import pytest

from pdestream import generator
from pdestream.generator import ics
from pdestream.generator.sampler import sample, sample_keys
from pdestream.generator.spectral.fourier import Grid

KINDS = {"fourier": (ics.FourierSeries(), 1), "fourier 2 fields": (ics.FourierSeries(max_mode=4, decay=0.5), 2),
         "grf": (ics.GaussianRandomField(), 1), "grf nonzero mean": (ics.GaussianRandomField(mean=0.3, zero_mean=False), 1),
         "spots": (ics.GrayScottSpots(), 2), "sines": (ics.RandomSines(), 1),
         "sines normalised 2 fields": (ics.RandomSines(normalise=True, window_prob=1.0), 2)}


def bits(x) -> np.ndarray:
    return np.asarray(x).view(np.uint32)


def test_every_ic_kind_has_a_latent():
    # a new kind must say how a proposal steers it (or the test names it)
    assert all(isinstance(cls(), ics.LatentIC) for cls in ics.IC_KINDS.values()), list(ics.IC_KINDS)


GRIDS = {"1d": Grid(1, 64, 1.0), "2d": Grid(2, 24, 2.0)}
ROUND_TRIPS = [(name, g) for name, (ic, _) in KINDS.items() for g in GRIDS  # each kind on the dimensions it serves
               if GRIDS[g].ndim in getattr(ic, "ndims", (1, 2))]


@pytest.mark.parametrize("name, grid", ROUND_TRIPS)
def test_latent_round_trip_is_the_keys_ic_bit_for_bit(name, grid):
    ic, n_fields = KINDS[name]
    grid = GRIDS[grid]
    size = ic.latent_size(grid, n_fields)
    assert 0 < size <= ics.MAX_LATENT
    kind, a, b = ic.latent_prior(grid, n_fields)
    assert kind in ("normal", "uniform") and a.shape == b.shape == (size,)
    for seed in range(3):
        key = jax.random.key(seed)
        z = ic.latent_from_key(key, grid, n_fields)
        assert z.shape == (size,) and z.dtype == np.float32
        assert np.array_equal(bits(ic.ic_from_latent(z, key, grid, n_fields)), bits(ic.sample(key, grid, n_fields)))
        # and the latent steers: another latent, another field (the key's rest unchanged)
        other = ic.ic_from_latent(np.asarray(z) * 0.5 + 0.1, key, grid, n_fields)
        assert not np.array_equal(np.asarray(other), np.asarray(ic.sample(key, grid, n_fields)))


def test_a_latent_is_capped_and_its_prior_is_the_keys_law():
    ic = ics.GaussianRandomField()
    grid = Grid(2, 64, 1.0)  # ~1400 band modes: the latent keeps the leading ones
    assert ic.latent_size(grid, 1) == ics.MAX_LATENT
    # the key's latent coordinates are about N(0, std^2) with the declared std (2000 draws: 4 sigma ~ 3%)
    grid = Grid(1, 64, 1.0)
    z = np.stack([np.asarray(ic.latent_from_key(jax.random.key(s), grid, 1)) for s in range(200)])
    kind, mean, std = ic.latent_prior(grid, 1)
    assert kind == "normal" and abs(z.std() / std[0] - 1) < 0.03 and abs(z.mean()) < 0.05


@pytest.mark.parametrize("name, grid", ROUND_TRIPS)
def test_latents_drawn_from_the_prior_give_the_keys_law(name, grid):
    # what a proposal's uniform draws rely on: a latent drawn from latent_prior, with the rest of the draw from another
    # key, is a draw of the IC distribution (mean energy within 4 standard errors over 512 draws each way). In 2D the
    # rfft's real plane holds conjugate twins: set independently they halved those modes' energy (a GRF's by 16%)
    ic, n_fields = KINDS[name]
    grid = GRIDS[grid]
    kind, a, b = ic.latent_prior(grid, n_fields)
    rng = np.random.default_rng(0)
    z = a + b * rng.standard_normal((512, a.size)) if kind == "normal" else rng.uniform(a, b, (512, a.size))
    keys = jax.random.split(jax.random.key(1), 1024)
    drawn = jax.jit(jax.vmap(lambda k: ic.sample(k, grid, n_fields)))(keys[:512])
    given = jax.jit(jax.vmap(lambda l, k: ic.ic_from_latent(l, k, grid, n_fields)))(np.float32(z), keys[512:])
    energy = [np.asarray(u, np.float64).reshape(512, -1).var(1) for u in (drawn, given)]
    se = np.hypot(*(e.std() / np.sqrt(512) for e in energy))
    assert abs(energy[0].mean() - energy[1].mean()) < 4 * se, (energy[0].mean(), energy[1].mean(), se)


def _small(name="burgers1d"):
    return generator.get_pde(name).replace(n=32, n_frames=3)


def _keys_latents(pde, seed, idx):
    """The latent each sample's IC key draws, float32 [B, L] (the IC key is the second half of the sample key)."""
    return np.stack([np.asarray(pde.latent_from_key(jax.random.split(k)[1])) for k in sample_keys(seed, idx)])


@pytest.mark.parametrize("name", ["burgers1d", "kdv1d"])
def test_explicit_latent_alone_equals_in_batch_and_the_keys_own_is_the_drawn_sample(name):
    pde, idx = _small(name), np.arange(6)
    drawn = sample(pde, idx, seed=2)
    own = sample(pde, idx, seed=2, latent=_keys_latents(pde, 2, idx))
    assert np.array_equal(bits(own.u), bits(drawn.u))
    rng = np.random.default_rng(0)
    z = np.full((6, pde.latent_size()), np.nan)
    z[[1, 4]] = rng.standard_normal((2, pde.latent_size()))
    batch = sample(pde, idx, seed=2, latent=z, params={"nu": np.asarray(drawn.params["nu"])} if "nu" in pde.PARAMS
                   else None)
    for i in range(6):
        same = np.array_equal(bits(batch.u[i]), bits(drawn.u[i]))
        assert same == (i not in (1, 4)), i  # rows without a latent are the drawn samples; the others are not
    for i in (1, 4):
        alone = sample(pde, [i], seed=2, latent=z[i], params={k: float(v[i]) for k, v in drawn.params.items()})
        assert np.array_equal(bits(alone.u[0]), bits(batch.u[i]))


def test_a_walled_entry_draws_its_latent_on_its_box():
    pde = generator.get_pde("diffusion1d").replace(n=32, n_frames=3, bc="dirichlet")
    idx = np.arange(3)
    own = sample(pde, idx, seed=0, latent=_keys_latents(pde, 0, idx))
    assert np.array_equal(bits(own.u), bits(sample(pde, idx, seed=0).u))


def test_bad_latents_are_refused_in_one_line():
    pde = _small()
    size = pde.latent_size()
    for latent, words in [(np.zeros(size + 1), "expected"), (np.zeros((2, size)), "expected"),
                          (np.r_[np.nan, np.zeros(size - 1)], "not finite"), (np.full(size, np.inf), "not finite")]:
        with pytest.raises(ValueError, match=words) as err:
            sample(pde, [0, 1, 2], latent=latent)
        assert "\n" not in str(err.value)
    euler = generator.get_pde("euler1d")
    assert euler.latent_size() == 0
    with pytest.raises(ValueError, match="no latent coordinates"):
        sample(euler, [0], latent=np.zeros(3))
