import jax
import numpy as np
import pytest

from pdestream.generator.domains import Choice, Fixed, LogUniform, Uniform, parse_domain


@pytest.mark.parametrize("text, expected", [
    ("0.5", Fixed(0.5)), ("fixed(2)", Fixed(2.0)), (" uniform( 0.1 , 1 ) ", Uniform(0.1, 1.0)),
    ("loguniform(1e-3, 1e-1)", LogUniform(1e-3, 1e-1)), ("choice(1, 2.5, 4)", Choice((1.0, 2.5, 4.0))),
    ("LogUniform(1e-3,1e-1)", LogUniform(1e-3, 1e-1)), (3, Fixed(3.0)),
])
def test_parse(text, expected):
    assert parse_domain(text) == expected
    assert parse_domain(str(expected)) == expected  # str() round-trips


@pytest.mark.parametrize("text", ["uniform(1, 0.5)", "loguniform(0, 1)", "choice()", "uniform(1)",
                                  "__import__('os')", "uniform(nan, 1)", "", "exp(1)"])
def test_malformed_domains_are_refused(text):
    with pytest.raises(ValueError, match="uniform|choice|must|number|domain"):
        parse_domain(text)


def test_draws_stay_in_the_domain_with_the_right_shape_of_distribution():
    keys = jax.random.split(jax.random.key(0), 20000)
    lo, hi = 1e-3, 1e-1
    draws = np.asarray(jax.vmap(LogUniform(lo, hi).sample)(keys))
    assert draws.min() >= lo and draws.max() <= hi
    assert abs(np.median(draws) / np.sqrt(lo * hi) - 1) < 0.05  # log-uniform: median is the geometric mean
    u = np.asarray(jax.vmap(Uniform(-1.0, 3.0).sample)(keys))
    assert u.min() >= -1 and u.max() < 3 and abs(u.mean() - 1.0) < 0.05
    c = np.asarray(jax.vmap(Choice((0.5, 2.0)).sample)(keys))
    assert set(np.unique(c)) == {0.5, 2.0} and abs((c == 2.0).mean() - 0.5) < 0.02
