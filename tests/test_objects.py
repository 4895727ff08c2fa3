import numpy as np
import pytest

import diffnurbs as dn
from diffnurbs import io
from diffnurbs._objects import PROFILES, QUARTER_HANDLE, design_object, revolution_patches


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_shipped_objects_match_their_generator(name):
    shipped, generated = io.load_object(name), design_object(name)
    assert len(shipped) == len(generated) > 0
    for a, b in zip(shipped, generated, strict=True):
        np.testing.assert_allclose(a.control_points, b.control_points, atol=1e-12)


def test_revolution_patches_follow_the_profile():
    profile = dn.NURBSCurve(np.array(PROFILES["vase"]), 3)
    u = np.linspace(0, 1, 40)
    v = np.linspace(0, 1, 40)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    # The cubic quarter circle's radius error, max over its parameter (known bound 2.7e-4).
    quarter = dn.NURBSCurve(np.array([[1, 0], [1, QUARTER_HANDLE], [QUARTER_HANDLE, 1], [0, 1]]), 3)
    bound = np.abs(np.linalg.norm(quarter(np.linspace(0, 1, 2001)), axis=-1) - 1).max()
    assert 2.6e-4 < bound < 2.8e-4
    for patch in revolution_patches(profile):
        points = np.asarray(patch(uu, vv))
        r = np.linalg.norm(points[..., :2], axis=-1)
        # At v = 0 and v = 1 the patch lies on its profile exactly; in between, the distance
        # from the axis is the profile's radius times the quarter circle's, within the bound.
        ends = r[:, [0, -1]]
        np.testing.assert_allclose(ends[:, 0], ends[:, 1], atol=1e-14)
        ratio = r[r[:, 0] > 1e-9] / r[r[:, 0] > 1e-9][:, :1]
        assert np.all(np.abs(ratio - 1) <= bound * 1.01)
        np.testing.assert_allclose(points[..., 2], np.broadcast_to(points[:, :1, 2], vv.shape))


def test_neighbouring_patches_share_their_edges():
    patches = design_object("cup")
    for k in range(0, len(patches), 4):
        ring = patches[k : k + 4]
        for a, b in zip(ring, ring[1:] + ring[:1], strict=True):
            np.testing.assert_allclose(a.control_points[:, -1], b.control_points[:, 0], atol=1e-14)


def test_unknown_objects_and_bad_profiles():
    with pytest.raises(ValueError, match="no object 'teacup'"):
        io.load_object("teacup")
    with pytest.raises(ValueError, match="unknown object"):
        design_object("teacup")
    with pytest.raises(ValueError, match="non-rational cubic profile"):
        revolution_patches(dn.NURBSCurve(np.zeros((3, 2)), 2))
