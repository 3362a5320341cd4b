"""`match_shapes` and `functional_map` match connected surfaces: a mesh of several components is refused before anything is computed."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import ddgjax.matching._match as match_module
from ddgjax import RESULTS, DDGInputError
from ddgjax.matching import descriptors, functional_map, match_shapes, spectral_shape
from ddgjax.mesh import Mesh


def _two_copies(mesh: Mesh, shift=(3.0, 0.0, 0.0)) -> Mesh:
    """`mesh` and a translated copy of it, disjoint: two connected components."""
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    return Mesh.from_arrays(np.concatenate([V, V + np.asarray(shift)]), np.concatenate([F, F + len(V)]))


def _touching_at_a_vertex(mesh: Mesh) -> Mesh:
    """`mesh` and its mirror image through its vertex of largest x, sharing that vertex only (a bowtie)."""
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    n, tip = len(V), int(np.argmax(V[:, 0]))
    mirrored = V * np.array([-1.0, 1.0, 1.0]) + np.array([2 * V[tip, 0], 0.0, 0.0])
    others = np.setdiff1d(np.arange(n), [tip])
    index = np.full(n, tip)
    index[others] = n + np.arange(others.size)
    return Mesh.from_arrays(np.concatenate([V, mirrored[others]]), np.concatenate([F, index[F][:, ::-1]]))


@pytest.mark.parametrize("which", ["target", "source", "both"])
@pytest.mark.parametrize("shape", ["icosphere", "spot"])
def test_a_mesh_of_two_components_is_refused_before_anything_is_computed(icosphere3, data_mesh, monkeypatch, which, shape):
    one = icosphere3 if shape == "icosphere" else data_mesh("spot.obj")
    two = _two_copies(one)

    def refuse(*args, **kwargs):
        raise AssertionError("computed before refusing")

    monkeypatch.setattr(match_module, "spectral_shape", refuse)
    source, target = {"target": (one, two), "source": (two, one), "both": (two, _two_copies(one, (0.0, 5.0, 0.0)))}[which]
    refused = "source_mesh" if which != "target" else "target_mesh"
    for throw in (True, False):
        with pytest.raises(DDGInputError, match=f"{refused}: match_shapes matches connected surfaces.* 2 connected components"):
            match_shapes(source, target, throw=throw)


@pytest.mark.parametrize("which", ["source", "target"])
def test_functional_map_called_directly_refuses_a_shape_of_two_components(which, icosphere1):
    """The refusal also guards a direct `functional_map` call: the two spheres' two zero eigenvalues
    (measured without the refusal: map entries of 50 to 500 at k = 10 to 30 in the rows of the
    target's zero eigenvalues, where a map between isometric shapes has entries of at most 1)."""
    sphere = icosphere1
    one, two = spectral_shape(sphere, 8), spectral_shape(_two_copies(sphere), 8)
    assert np.all(np.abs(np.asarray(two.values[:2])) < 1e-10) and two.values[2] > 1  # two zero eigenvalues
    source, target = (two, one) if which == "source" else (one, two)
    with pytest.raises(DDGInputError, match=f"{which}: functional_map matches connected surfaces.* 2 connected"):
        functional_map(source, target, descriptors(source), descriptors(target))
    fitted = np.asarray(functional_map(one, one, descriptors(one), descriptors(one)))
    assert np.abs(fitted).max() < 1 + 1e-6  # one component against itself: entries of an isometry's map


@pytest.mark.slow
def test_components_that_share_a_vertex_are_one_and_are_matched(icosphere2):
    """A bowtie's two spheres are joined through their shared vertex: one zero eigenvalue, not refused."""
    bowtie = _touching_at_a_vertex(icosphere2)
    assert bowtie.topology.n_components == 2  # two edge-connected components of faces ...
    rng = np.random.default_rng(0)
    moved = bowtie.with_vertices(
        jnp.asarray(np.asarray(bowtie.vertices) * (1 + 0.02 * rng.standard_normal((bowtie.n_vertices, 1))))
    )
    result = match_shapes(bowtie, moved, k=10, k_final=20, throw=False)
    values = np.asarray(result.source.values)
    assert abs(values[0]) < 1e-10 and values[1] > 1e-3  # ... but one component of the Laplacian
    assert result.result == RESULTS.successful
    assert np.abs(np.asarray(result.initial_functional_map)).max() < 1.1
