"""Matching through a clean template (the ``template`` matcher)."""

from __future__ import annotations

import numpy as np
import pytest

from topomatch.matching import MATCHERS, NotFittedError, make_matcher
from topomatch.matching.deform import ACCURATE, map_from_deformed
from topomatch.matching.template import compose_through_template
from topomatch.mesh import TriangleMesh

from ._truth import euclidean_errors

# a cheaper registration than the default, enough for the built-in figure (two starts
# instead of ACCURATE's five: the starts are still judged against each other)
FAST = {"n_samples": 800, "coarse_nodes": 100, "fine_nodes": 250, "limb_rounds": 1, "n_starts": 2}


def test_compose_through_template():
    t2m = np.array([2, 0, 1, 2])
    m2s = np.array([5, 6, 7])
    np.testing.assert_array_equal(compose_through_template(t2m, m2s), [7, 5, 6, 7])
    with pytest.raises(ValueError, match="outside"):
        compose_through_template(np.array([3]), m2s)
    with pytest.raises(ValueError, match="1-D"):
        compose_through_template(np.zeros((2, 2), int), m2s)


def test_template_needs_a_template(tmp_path, builtin):
    assert MATCHERS["template"].requires_fit
    with pytest.raises(NotFittedError):
        make_matcher("template").match(builtin["syn01"].mesh, builtin["syn02"].mesh)
    # shapes without a null shape among them, and no model file
    with pytest.raises(ValueError, match="no template"):
        make_matcher("template").fit([builtin["syn01"], builtin["syn02"]])
    with pytest.raises(FileNotFoundError, match="not found"):
        make_matcher("template", model=str(tmp_path / "none.off")).fit([])
    with pytest.raises(ValueError, match="bad deform"):
        make_matcher("template", deform={"bogus": 1}).fit([builtin["syn00"]])
    with pytest.raises(ValueError, match="limb_rounds"):
        make_matcher("template", deform={"limb_rounds": -1}).fit([builtin["syn00"]])
    with pytest.raises(ValueError, match="copy_starts"):
        make_matcher("template", copy_starts=0).fit([builtin["syn00"]])


def test_template_registers_through_working_copies_with_copy_starts(builtin):
    # a registration through working copies runs every start at every copy size, so
    # the template uses copy_starts (1) there instead of ACCURATE's five starts
    small = builtin["syn07"].mesh
    m = make_matcher("template").fit([builtin["syn00"]])
    deformer = m._deformer()
    assert m._deformer_for(small, deformer) is deformer and deformer.n_starts == 5
    above = make_matcher("template", deform={"working_vertices": small.n_vertices - 1}).fit([builtin["syn00"]])
    d = above._deformer()
    assert above._deformer_for(small, d).n_starts == 1
    assert above._deformer_for(small, d).get_params() == {**d.get_params(), "n_starts": 1}
    # None: the deformer's own n_starts at every size
    assert make_matcher("template", deform={"working_vertices": small.n_vertices - 1}, copy_starts=None).fit(
        [builtin["syn00"]]
    )._deformer_for(small, d).n_starts == 5
    assert above._deformer_for(small, d) is not d and d.n_starts == 5


@pytest.fixture(scope="module")
def fitted(builtin):
    m = make_matcher("template", deform=FAST)
    m.fit([builtin[n] for n in builtin.names])
    return m


def test_template_is_deform_when_the_source_is_the_template(fitted, builtin):
    assert fitted.template_name_ == "syn00"
    src, tgt = builtin["syn00"].mesh, builtin["syn07"].mesh
    c = fitted.match(src, tgt)
    assert c.info["registrations"] == {"target": "computed", "source": "is the template"}
    direct = make_matcher("deform", **{**ACCURATE, **FAST}).match(src, tgt)
    np.testing.assert_array_equal(c.p2p_21, direct.p2p_21)
    # two sampling starts per registration, the better kept
    assert [len(info["runs"]) for _, info in fitted.registrations_.values()] == [2]
    assert len(c.info["runs"]["target"]["runs"]) == 2 and "source" not in c.info["runs"]
    # the template's registrations use the accurate settings unless told otherwise
    assert make_matcher("template")._deformer().get_params()["n_starts"] == ACCURATE["n_starts"] == 5
    assert make_matcher("template", deform={"n_starts": 1})._deformer().get_params()["n_starts"] == 1


def test_template_composes_the_two_registrations(fitted, builtin):
    s, t = builtin["syn08"], builtin["syn07"]
    c = fitted.match(s.mesh, t.mesh)
    # syn07 was registered by the previous test (same matcher object): reused
    assert c.info["registrations"] == {"target": "reused", "source": "computed"}
    # the composition, recomputed from the two registrations
    deform = make_matcher("deform", **{**ACCURATE, **FAST})
    template = builtin["syn00"].mesh
    d_t, _ = deform.register(template, t.mesh)
    d_s, _ = deform.register(template, s.mesh)
    t2m = map_from_deformed(t.mesh, d_t, template.faces)
    m2s = map_from_deformed(TriangleMesh(d_s, template.faces), s.mesh.vertices, s.mesh.faces)
    np.testing.assert_array_equal(c.p2p_21, m2s[t2m])
    # and it is a good map: most target vertices land near their true source vertex
    assert np.median(euclidean_errors(t, s, c.p2p_21)) < 0.05
    # the reverse pair reuses both registrations
    back = fitted.match(t.mesh, s.mesh)
    assert back.info["registrations"] == {"target": "reused", "source": "reused"}


def test_template_model_file_round_trip(tmp_path, fitted, builtin):
    path = fitted.save_model(tmp_path / "tmpl")
    assert path.suffix == ".off" and path.is_file()
    m = make_matcher("template", model=str(path), deform=FAST).fit([])
    np.testing.assert_allclose(m.template_.vertices, builtin["syn00"].mesh.vertices, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(m.template_.faces, builtin["syn00"].mesh.faces)
