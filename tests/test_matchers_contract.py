import numpy as np
import pytest

from topomatch.matching import MATCHERS, Matcher, NotFittedError, make_matcher


@pytest.mark.parametrize("name", sorted(MATCHERS))
def test_estimator_contract(name):
    cls = MATCHERS[name]
    m = cls()
    assert isinstance(m, Matcher)
    params = m.get_params()
    clone = cls(**params)
    assert clone.get_params() == params
    assert m.set_params(**params) is m
    with pytest.raises(ValueError, match="no hyperparameter"):
        m.set_params(definitely_not_a_param=1)
    assert name in repr(m) or cls.__name__ in repr(m)


def test_make_matcher_errors():
    with pytest.raises(ValueError, match="unknown method"):
        make_matcher("nope")
    with pytest.raises(ValueError, match="bad hyperparameters"):
        make_matcher("descriptor-nn", bogus=3)


def test_oracle_requires_fit(builtin):
    o = make_matcher("oracle")
    with pytest.raises(NotFittedError):
        o.match(builtin["syn00"].mesh, builtin["syn01"].mesh)
    o.fit([builtin[n] for n in builtin.names])
    c = o.match(builtin["syn00"].mesh, builtin["syn01"].mesh)
    assert c.p2p_21.shape == (builtin["syn01"].n_vertices,)


def test_descriptor_nn_is_deterministic_and_exact_on_identical_shapes(sphere):
    from topomatch.mesh import TriangleMesh

    m = make_matcher("descriptor-nn", k=30, n_descriptors=20)
    a = m.match(sphere, sphere).p2p_21
    b = m.match(TriangleMesh(sphere.vertices, sphere.faces), sphere).p2p_21
    np.testing.assert_array_equal(a, b)
    assert a.shape == (sphere.n_vertices,) and a.min() >= 0
