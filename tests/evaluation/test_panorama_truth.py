"""The mosaic bench's truths (tectum.evaluation.panorama): the ray cast
against the simulator's own renderer, the panorama-only case against
``truth_panorama``, and ``swept_mask`` against the projection written out."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from tectum.evaluation.panorama import _cast, cast_panorama, swept_mask, truth_panorama
from tectum.evaluation.suites._map_mosaic import room_scene
from tectum.sources.simulate import load_scene, simulate
from tectum.sources.simulate.scenes import compile_scene


def test_ray_cast_matches_the_rendered_frame_of_a_translating_camera() -> None:
    scene = room_scene((48, 36), 0.5, 200_000)
    _, truth = simulate(scene, 200_000, truth_fps=10)
    cs = compile_scene(scene)
    k = len(truth["frame_t"]) - 1
    R, p = cs.trajectory.pose(truth["frame_t"][k] * 1e-6)
    assert p[0] > 0.2  # the camera has moved: the cast starts at its centre, not the origin
    u, v = np.meshgrid(np.arange(48.0), np.arange(36.0))
    rays = np.stack([(u.ravel() - cs.cx) / cs.f, (v.ravel() - cs.cy) / cs.f, np.ones(u.size)], axis=1) @ R.T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    val, rng = np.empty(len(rays)), np.empty(len(rays))
    _cast(p, rays, cs.patches, cs.pano, float(cs.bg[0]), cs.tex_data, cs.tex_table, val, rng)
    np.testing.assert_allclose(val.reshape(36, 48), truth["frame_intensity"][k], atol=1e-6)
    z = rng * (rays @ R[:, 2])  # range along the ray -> depth along the optical axis
    np.testing.assert_allclose(z.reshape(36, 48), truth["frame_depth"][k], rtol=1e-5)


def test_panorama_only_scene_casts_to_truth_panorama() -> None:
    cs = compile_scene(load_scene("rotation", (32, 24)))
    R0 = Rotation.from_rotvec([0.2, -0.4, 0.1]).as_matrix()
    img, rng = cast_panorama(cs, 128, R0, np.array([5.0, -1.0, 2.0]), supersample=2)
    np.testing.assert_allclose(img, truth_panorama(cs, 128, R0, supersample=2), atol=1e-12)
    assert np.isinf(rng).all()


def test_swept_mask_against_the_projection_written_out() -> None:
    Rs = Rotation.from_rotvec(np.random.default_rng(0).normal(0, 0.6, (5, 3))).as_matrix()
    f, cx, cy, size = 30.0, 15.5, 11.5, (32, 24)
    got = swept_mask(96, Rs, f, cx, cy, size)
    az = (np.arange(96) + 0.5) * 2 * np.pi / 96 - np.pi
    el = (np.arange(48) + 0.5) * np.pi / 48 - np.pi / 2
    want = np.zeros((48, 96), bool)
    for i, e in enumerate(el):
        for j, a in enumerate(az):
            d = np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])
            for R in Rs:
                c = R.T @ d
                if c[2] > 0:
                    x, y = f * c[0] / c[2] + cx, f * c[1] / c[2] + cy
                    want[i, j] |= -0.5 <= x < size[0] - 0.5 and -0.5 <= y < size[1] - 0.5
    assert want.sum() > 100
    np.testing.assert_array_equal(got, want)
