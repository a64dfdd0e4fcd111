"""Fits lost as a whole (arteq.fit.torso_turns): the lower torso turned, and the fitter keeping it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from arteq.body.skeleton import NUM_JOINTS, global_to_local, local_to_global
from arteq.fit.torso_turns import CHAINS, PREFIX, TURNS, torso_starts
from fit_helpers import posed as _posed


def _random_rotations(n: int, seed: int) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.random(n, random_state=seed).as_matrix()


def _globals(local: np.ndarray) -> np.ndarray:
    return local_to_global(torch.as_tensor(local)).numpy()


def test_turns_are_the_named_rotations():
    """Each turn is a proper rotation by its angle about its axis (x left-right, y up, z forward)."""
    want = {"pitch90": (0, 90), "pitch-90": (0, -90), "pitch180": (0, 180), "turn180": (1, 180),
            "roll180": (2, 180)}  # fmt: skip
    assert set(TURNS) == set(want)
    for name, (axis, deg) in want.items():
        t = TURNS[name]
        assert np.allclose(t @ t.T, np.eye(3)) and np.isclose(np.linalg.det(t), 1.0)
        e = np.eye(3)[axis]
        assert np.allclose(t @ e, e), name  # the axis stays
        other = np.eye(3)[(axis + 1) % 3]
        angle = np.degrees(np.arctan2(np.cross(other, t @ other) @ e, other @ (t @ other)))
        assert np.isclose(angle, deg) or np.isclose(abs(angle), 180) and abs(deg) == 180, (name, angle)


def test_torso_starts_turn_the_chain_and_keep_every_other_part():
    """Every chain x turn start: the chain's global rotations are the fit's turned in their own frame, every
    other part's global rotation is the fit's (its local rotation rebuilt)."""
    fit_global = _random_rotations(NUM_JOINTS, 0)
    starts = torso_starts(fit_global)
    assert len(starts) == len(CHAINS) * len(TURNS)
    for chain, parts in CHAINS.items():
        for turn, t in TURNS.items():
            g = _globals(starts[f"{PREFIX}{chain}_{turn}"])
            for j in range(NUM_JOINTS):
                want = fit_global[j] @ t if j in parts else fit_global[j]
                assert np.allclose(g[j], want, atol=1e-10), (chain, turn, j)


def test_a_torso_read_upside_down_has_the_truth_among_the_starts():
    """A reading whose pelvis and lower spine are the truth's pitched by half a turn (what the network gives a
    plough or a wheel) gives back the truth's rotations exactly from ``torso_to_spine2_pitch180``."""
    truth = _globals(_random_rotations(NUM_JOINTS, 1))
    read = truth.copy()
    read[list(CHAINS["to_spine2"])] = read[list(CHAINS["to_spine2"])] @ TURNS["pitch180"].T
    start = torso_starts(read)[PREFIX + "to_spine2_pitch180"]
    assert np.allclose(_globals(start), truth, atol=1e-10)
    assert not np.allclose(_globals(global_to_local(torch.as_tensor(read)).numpy()), truth, atol=1e-3)


def test_torso_starts_refuse_a_wrong_shape():
    with pytest.raises(ValueError, match=r"\[22, 3, 3\]"):
        torso_starts(np.zeros((21, 3, 3)))


@pytest.fixture(scope="module")
def body(anny22):
    return anny22


def _upside_down(body, tmp_path, tiny_net):
    """A scan (5000 points, 3 mm noise), its truth, a tiny checkpoint and a fitter class whose "network" reads
    the scan's pelvis and lower spine pitched by half a turn, every other part's global rotation right."""
    from arteq.fit.demo import synthetic_scan
    from arteq.geometry.sampling import sample_surface
    from fit_helpers import reading_of, write_tiny_checkpoint

    s = synthetic_scan(body, "test_id", 2, 5000, offset=0.0, rotate=True)
    truth = _posed(body, s["pose"], s["betas"], s["transl"])
    g = truth["global_rotmats"].copy()
    low = list(CHAINS["to_spine2"])
    g[low] = g[low] @ TURNS["pitch180"].T
    pose = global_to_local(torch.as_tensor(g)).numpy()
    read = _posed(body, pose, s["betas"], s["transl"])
    gen = torch.Generator().manual_seed(5)
    pts, _, _ = sample_surface(
        torch.as_tensor(truth["vertices"], dtype=torch.float32), body.faces, 5000, gen, noise_std=0.003
    )
    ckpt = write_tiny_checkpoint(tmp_path / "tiny.ckpt", tiny_net)
    return truth, pts.double().numpy(), ckpt, reading_of(read["vertices"], pose, s["betas"], s["transl"])


def test_the_fitter_turns_a_torso_read_upside_down_back_and_says_so(body, tmp_path, tiny_net):
    """Through ``Fitter``: a "network" that reads the scan's pelvis and lower spine pitched by half a turn
    (every other part's global rotation right) gives a fit lost as a whole; with the torso step the fit comes
    back to the truth and its record names the start kept, without it stays lost."""
    from arteq.fit.crossing import CrossingConfig

    truth, pts, ckpt, Upside = _upside_down(body, tmp_path, tiny_net)
    v2v, rec = {}, {}
    for on in (True, False):
        cfg = CrossingConfig(torso=on, torso_once=False)  # the step in the first fit (no retry needed)
        f = Upside(ckpt=ckpt, device="cpu", anny=False, retries=0, crossing=cfg)
        r = f.fit_points(pts)
        v2v[on] = float(np.linalg.norm(r.vertices - truth["vertices"], axis=1).mean() * 100)
        rec[on] = r.crossing or {}
    assert rec[True]["taken"].startswith(PREFIX), rec[True]
    assert f"{PREFIX}to_spine2_pitch180 (torso 1)" in rec[True]["tried_cm"]
    assert not any(PREFIX in k for k in rec[False].get("tried_cm", {})), rec[False]
    assert v2v[True] < 1.5 < 3.0 < v2v[False], v2v


def test_torso_once_turns_the_kept_fit_only(body, tmp_path, tiny_net):
    """``CrossingConfig.torso_once``: the same upside-down reading, with the retries on: the first fit and the
    retries skip the torso step, the fit the retries keep takes it once (its own seconds), and the fit comes
    back as with the step in every fit."""
    from arteq.fit.crossing import CrossingConfig

    truth, pts, ckpt, Upside = _upside_down(body, tmp_path, tiny_net)
    assert CrossingConfig().torso_once  # the default
    f = Upside(ckpt=ckpt, device="cpu", anny=False, retries=1)
    assert f._torso_deferred
    r = f.fit_points(pts)
    v2v = float(np.linalg.norm(r.vertices - truth["vertices"], axis=1).mean() * 100)
    assert r.retry is not None and "torso" in r.timings, (r.retry, r.timings)
    assert min(r.retry["scores_cm"]) > 3.0, r.retry  # no fit before the kept one was turned
    assert f"{PREFIX}to_spine2_pitch180 (torso 1)" in r.crossing["taken"].split("+"), r.crossing
    once = [k for k in r.crossing["tried_cm"] if k.startswith(PREFIX) and k.endswith("(torso 1)")]
    assert len(once) == 20, r.crossing["tried_cm"]
    assert r.status == "uncertain" and "refitted" in r.quality["flags"], r.quality["flags"]
    assert v2v < 1.5, v2v
