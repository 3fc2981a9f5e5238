"""generator.lazy_jax: stand-ins that import JAX on first use, and forward everything to it afterwards."""

import subprocess
import sys

import numpy as np

from pdestream.generator import lazy_jax


def test_importing_the_generator_does_not_import_jax_and_first_use_does():
    script = ("import sys\nimport pdestream.generator\nfrom pdestream.generator.lazy_jax import jnp\n"
              "print('jax' in sys.modules)\nx = jnp.arange(3)\nprint('jax' in sys.modules, type(x).__module__)")
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert res.stdout.split()[:2] == ["False", "True"] and "jax" in res.stdout.split()[2], res.stdout + res.stderr


def test_the_stand_in_forwards_reads_and_writes_to_the_module(monkeypatch):
    import jax.numpy

    stand_in = lazy_jax.LazyModule("jax.numpy")
    assert stand_in.float32 is jax.numpy.float32 and "jax.numpy" in repr(stand_in)
    monkeypatch.setattr(stand_in, "a_test_attribute", 3, raising=False)
    assert jax.numpy.a_test_attribute == 3  # the module itself, as monkeypatching jnp did before


def test_jit_is_made_once_and_keeps_static_arguments():
    calls = []

    @lazy_jax.jit(static_argnums=1)
    def scale(x, k: int):
        calls.append(k)  # traced once per static k
        return x * k

    assert scale.__name__ == "scale"
    for _ in range(3):
        np.testing.assert_array_equal(np.asarray(scale(np.arange(3.0), 2)), [0.0, 2.0, 4.0])
    np.testing.assert_array_equal(np.asarray(scale(np.arange(3.0), 3)), [0.0, 3.0, 6.0])
    assert calls == [2, 3]

    @lazy_jax.jit
    def plain(x):
        return x + 1

    np.testing.assert_array_equal(np.asarray(plain(np.zeros(2))), [1.0, 1.0])
