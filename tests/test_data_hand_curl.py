"""``data.hand_curl``: training clouds of bodies with curled fingers (arteq.body.hands), flat otherwise."""

from __future__ import annotations

import numpy as np
import pytest
import torch


@pytest.fixture(scope="module")
def body():
    pytest.importorskip("anny")
    from arteq.body import load_body_model

    return load_body_model("anny22")


def _dataset(body, **kw):
    from arteq.data.dataset import BodyScanDataset
    from arteq.data.poses import SyntheticIDPoses

    return BodyScanDataset(SyntheticIDPoses(), body, "train", 8, seed=3, num_points=3000, **kw)


def test_curled_hands_change_only_the_hands_points_and_keep_their_labels(body):
    from scipy.spatial import cKDTree

    flat, curled = _dataset(body), _dataset(body, hand_curl=1.0)
    off = _dataset(body, hand_curl=0.0)
    hand_parts = torch.tensor([20, 21])
    moved = 0
    for i in range(4):
        a, b, c = flat[i], curled[i], off[i]
        for k in a:  # hand_curl 0: the very samples drawn without the option
            assert torch.equal(a[k], c[k]), k
        assert torch.equal(a["pose"], b["pose"]) and torch.equal(a["betas"], b["betas"])  # the same draw
        curl = curled._curl((3, "train", i))
        assert curl is not None and curl.shape == (1, 2)
        # the curled sample lies on the body with its fingers curled (the dataset's own curl), its hands'
        # points off the flat body's hands
        from arteq.body.hands import hands_for
        from arteq.body.lbs import skin
        from arteq.body.skeleton import PARENTS

        with torch.no_grad():
            o = body(betas=b["betas"][None], pose=b["pose"][None], transl=b["transl"][None])
        rest, rj = body.shape(b["betas"][None])
        cv = skin(hands_for(body)(rest, curl.float()), rj, b["pose"][None], body.lbs_weights, PARENTS, None,
                  b["transl"][None])[0][0]  # fmt: skip
        hv = torch.isin(body.part_labels, hand_parts)
        on_hand = torch.isin(b["labels"], hand_parts)
        assert on_hand.sum() > 50  # the fingers stay the hands' part
        to_curled = cKDTree(cv[hv].numpy()).query(b["points"][on_hand].numpy())[0]
        to_flat = cKDTree(o.vertices[0][hv].numpy()).query(b["points"][on_hand].numpy())[0]
        if curl.max() > 0.5:
            moved += 1
            assert to_curled.mean() < 0.6 * to_flat.mean(), (i, curl, to_curled.mean(), to_flat.mean())
        on_curled = cKDTree(cv.numpy()).query(b["points"].numpy())[0]
        on_flat = cKDTree(o.vertices[0].numpy()).query(a["points"].numpy())[0]  # (a's body: the same draw)
        assert np.percentile(on_curled, 90) < 1.2 * np.percentile(on_flat, 90) + 1e-3
    assert moved >= 1


def test_hand_curl_is_checked(body, toy_body):
    with pytest.raises(ValueError, match="probability"):
        _dataset(body, hand_curl=1.5)
    with pytest.raises(ValueError, match="built from Anny"):
        _dataset(toy_body, hand_curl=0.5)
