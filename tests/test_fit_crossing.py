"""Crossed limbs (arteq.fit.crossing): the swapped start, and the swap kept only when it explains the scan."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from arteq.fit.crossing import (
    ALL_LIMBS,
    CHAINS,
    PAIRS,
    SWAPS,
    CrossingConfig,
    pairs_to_try,
    segment_gap,
    surface_score,
    swap_start,
)
from arteq.fit.refine import RefineConfig, body_tables
from fit_helpers import posed as _posed


@pytest.fixture(scope="module")
def body(anny22):
    return anny22


@pytest.fixture(scope="module")
def scene(body):
    from arteq.fit.demo import synthetic_scan

    s = synthetic_scan(body, "test_id", 2, 5000, offset=0.0, rotate=True)
    return s, _posed(body, s["pose"], s["betas"], s["transl"])


@pytest.mark.parametrize("pair", list(PAIRS))
def test_swap_start_points_each_segment_at_the_other_end(body, scene, pair):
    """Each segment of the pair turns about its own joint toward the other side's segment end (its children
    follow); every other part keeps its global rotation."""
    s, fit = scene
    new = _posed(
        body, swap_start(s["pose"], fit["global_rotmats"], fit["joints"], pair), s["betas"], s["transl"]
    )
    lj, rj, le, re = PAIRS[pair]
    for j, end, other in ((lj, le, re), (rj, re, le)):
        np.testing.assert_allclose(new["joints"][j], fit["joints"][j], atol=1e-5)  # the joint stays
        got = new["joints"][end] - new["joints"][j]
        want = fit["joints"][other] - fit["joints"][j]
        cos = got @ want / np.linalg.norm(got) / np.linalg.norm(want)
        assert cos > 1 - 1e-6, (pair, cos)
    moved = {lj, rj} | {k for k in range(22) if _descends(k, (lj, rj))}
    same = [k for k in range(22) if k not in moved]
    np.testing.assert_allclose(new["global_rotmats"][same], fit["global_rotmats"][same], atol=1e-5)


@pytest.mark.parametrize("chain", list(CHAINS))
def test_chain_swap_aims_every_segment_at_the_other_sides_end(body, scene, chain):
    """A whole limb swapped (upper arm and forearm, thigh and shin): each segment, moved by the turns before,
    points at where the other side's segment ended in the fit; the limb roots stay, the rest of the body
    keeps its global rotations."""
    s, fit = scene
    new = _posed(
        body, swap_start(s["pose"], fit["global_rotmats"], fit["joints"], chain), s["betas"], s["transl"]
    )
    first = PAIRS[CHAINS[chain][0]]
    for pair in CHAINS[chain]:
        lj, rj, le, re = PAIRS[pair]
        for j, end, other in ((lj, le, re), (rj, re, le)):
            got = new["joints"][end] - new["joints"][j]
            want = fit["joints"][other] - new["joints"][j]
            cos = got @ want / np.linalg.norm(got) / np.linalg.norm(want)
            assert cos > 1 - 1e-6, (chain, pair, cos)
    np.testing.assert_allclose(new["joints"][list(first[:2])], fit["joints"][list(first[:2])], atol=1e-5)
    same = [k for k in range(22) if not _descends(k, first[:2])]
    np.testing.assert_allclose(new["global_rotmats"][same], fit["global_rotmats"][same], atol=1e-5)
    # not a pair swap's start: the second segments are aimed again
    single = swap_start(s["pose"], fit["global_rotmats"], fit["joints"], CHAINS[chain][0])
    assert not np.allclose(single, swap_start(s["pose"], fit["global_rotmats"], fit["joints"], chain))


def test_all_limbs_swap_aims_every_segment_and_keeps_the_trunk(body, scene):
    """All four limbs at once (:data:`ALL_LIMBS`): every segment of both chains points at where the other
    side's segment ended in the fit; the trunk and head keep their global rotations; tried only where both
    chains are and the config asks for it."""
    s, fit = scene
    new = _posed(
        body, swap_start(s["pose"], fit["global_rotmats"], fit["joints"], ALL_LIMBS), s["betas"], s["transl"]
    )
    for pair in SWAPS[ALL_LIMBS]:
        lj, rj, le, re = PAIRS[pair]
        for j, end, other in ((lj, le, re), (rj, re, le)):
            got = new["joints"][end] - new["joints"][j]
            want = fit["joints"][other] - new["joints"][j]
            assert got @ want / np.linalg.norm(got) / np.linalg.norm(want) > 1 - 1e-6, pair
    roots = [PAIRS["upper_arms"][0], PAIRS["upper_arms"][1], PAIRS["thighs"][0], PAIRS["thighs"][1]]
    trunk = [k for k in range(22) if not _descends(k, roots)]
    np.testing.assert_allclose(new["global_rotmats"][trunk], fit["global_rotmats"][trunk], atol=1e-5)
    assert ALL_LIMBS not in pairs_to_try(fit["joints"], doubtful=True)
    on = CrossingConfig(all_limbs=True)
    assert pairs_to_try(fit["joints"], doubtful=True, config=on) == [*PAIRS, *CHAINS, ALL_LIMBS]
    assert ALL_LIMBS not in pairs_to_try(fit["joints"], doubtful=False, config=on)


def _descends(k, roots):
    from arteq.body.skeleton import PARENTS

    while k >= 0:
        if k in roots:
            return True
        k = PARENTS[k]
    return False


def test_pairs_to_try(scene):
    s, fit = scene
    gaps = {p: segment_gap(fit["joints"], p) for p in PAIRS}
    assert all(g > 0.15 for g in gaps.values()), gaps  # an everyday pose: no two segments close
    only_pairs = CrossingConfig(chain_near_m=0.0)
    assert pairs_to_try(fit["joints"], doubtful=False, config=only_pairs) == []
    assert pairs_to_try(fit["joints"], doubtful=True) == list(PAIRS) + list(CHAINS)
    assert pairs_to_try(fit["joints"], doubtful=True, config=CrossingConfig(chains=False)) == list(PAIRS)
    near = CrossingConfig(near_m=10.0)
    assert pairs_to_try(fit["joints"], doubtful=False, config=near) == list(PAIRS) + list(CHAINS)
    # a chain where every pair of it is tried, not where only one is
    lo, hi = sorted((gaps["upper_arms"], gaps["forearms"]))
    assert hi - lo > 1e-3, gaps
    one = CrossingConfig(near_m=0.5 * (lo + hi), chain_near_m=0.0)
    tried = pairs_to_try(fit["joints"], doubtful=False, config=one)
    assert "arms" not in tried and len({"upper_arms", "forearms"} & set(tried)) == 1
    # an everyday pose's arms hang: not raised, so no arms chain by nearness, however near
    far = CrossingConfig(chain_near_m=10.0)
    assert "arms" not in pairs_to_try(fit["joints"], doubtful=False, config=far)


def test_raised_arms_that_come_close_try_the_arms_chain(scene):
    """Arms overhead that come close (a crossing fitted as parallel arms) try the whole arms swapped."""
    from arteq.body.skeleton import JOINT_NAMES
    from arteq.fit.refine import branch_parts

    s, fit = scene
    j = {n: i for i, n in enumerate(JOINT_NAMES)}
    joints = np.array(fit["joints"], dtype=np.float64)
    up = joints[j["neck"]] - joints[j["pelvis"]]
    up /= np.linalg.norm(up)
    raised = joints.copy()
    for side in ("left", "right"):  # each arm mirrored about its shoulder's horizontal plane: overhead
        sh = j[f"{side}_shoulder"]
        arm = list(branch_parts(sh))
        raised[arm] -= 2 * ((joints[arm] - joints[sh]) @ up)[:, None] * up
    gap = max(segment_gap(raised, p) for p in CHAINS["arms"])
    tried = pairs_to_try(raised, doubtful=False, config=CrossingConfig(chain_near_m=gap + 1e-3))
    assert "arms" in tried and "upper_arms" not in tried and "forearms" not in tried
    assert "arms" not in pairs_to_try(raised, doubtful=False, config=CrossingConfig(chain_near_m=gap - 1e-3))
    assert "arms" not in pairs_to_try(joints, doubtful=False, config=CrossingConfig(chain_near_m=10.0))


def test_crossing_config_from_strings():
    cfg = CrossingConfig.from_strings(["chain_near_m=0.3", "chains=false"], near_m=0.2)
    assert (cfg.chain_near_m, cfg.chains, cfg.near_m) == (0.3, False, 0.2)
    with pytest.raises(ValueError, match="crossing setting 'chain=1'"):
        CrossingConfig.from_strings(["chain=1"])
    with pytest.raises(ValueError, match="is not of type bool"):
        CrossingConfig.from_strings(["chains=maybe"])


def test_a_crossing_is_found_and_a_good_fit_left_alone(body, scene):
    """A scan with crossed forearms fitted uncrossed: trying the swap recovers it (V2V down to the
    refinement's level); the scan of the uncrossed pose, fitted right, keeps its pose."""
    from arteq.fit.crossing import try_swaps
    from arteq.geometry.sampling import sample_surface

    s, fit = scene
    crossed_pose = swap_start(s["pose"], fit["global_rotmats"], fit["joints"], "forearms")
    crossed = _posed(body, crossed_pose, s["betas"], s["transl"])
    g = torch.Generator().manual_seed(0)
    subset = body_tables(body, 2000).m2s_subset.numpy()
    ref = RefineConfig()
    fit_t = {
        "local_rotmats": torch.as_tensor(np.stack([s["pose"]] * 2), dtype=torch.float32),
        "betas": torch.as_tensor(np.stack([s["betas"]] * 2), dtype=torch.float32),
        "transl": torch.as_tensor(np.stack([s["transl"]] * 2), dtype=torch.float32),
        **{k: torch.as_tensor(np.stack([fit[k]] * 2)) for k in ("vertices", "joints", "global_rotmats")},
    }
    clouds = []
    for verts in (crossed["vertices"], fit["vertices"]):
        pts, _, _ = sample_surface(
            torch.as_tensor(verts, dtype=torch.float32), body.faces, 5000, g, noise_std=0.003
        )
        clouds.append(pts.double().numpy())
    before = np.linalg.norm(fit["vertices"] - crossed["vertices"], axis=1).mean() * 100
    out = try_swaps(body, clouds, fit_t, subset, [["forearms"], ["forearms"]], ref)
    assert before > 3.0, before
    assert out[0]["taken"] == "forearms", out[0]
    after = np.linalg.norm(out[0]["vertices"].double().numpy() - crossed["vertices"], axis=1).mean() * 100
    assert after < 1.0, (before, after)
    assert out[0]["tried"]["forearms"] < min(out[0]["score"], out[0]["tried"]["none"])
    assert "stopped" not in out[0]
    # the right fit: the swap explains the scan worse than the fit refined again ("none"), already where
    # swaps that lose stop being refined
    assert out[1]["taken"] in ("", "none") and out[1]["tried"]["forearms"] > out[1]["tried"]["none"], out[1]
    assert out[1]["stopped"] == {"forearms": CrossingConfig().stop_at}
    assert surface_score(clouds[1], fit["vertices"], subset) == pytest.approx(out[1]["score"])
    # polished (CrossingConfig.polish_iters): the swap taken is refined on from where it ended (here cut
    # short at 6 iterations, not converged) and kept where it scores lower; a fit whose swap lost is not
    cfg = CrossingConfig(iters=6, stop_at=-1, polish_iters=0)
    short = try_swaps(body, clouds, fit_t, subset, [["forearms"], ["forearms"]], ref, cfg)
    pol = try_swaps(body, clouds, fit_t, subset, [["forearms"], ["forearms"]], ref,
                    dataclasses.replace(cfg, polish_iters=30))  # fmt: skip
    assert short[0]["taken"] == pol[0]["taken"] == "forearms"
    assert pol[0]["tried"] == pytest.approx(short[0]["tried"]) and "polish_cm" not in short[0]
    assert pol[0]["polish_cm"] < pol[0]["tried"]["forearms"]
    score = surface_score(clouds[0], pol[0]["vertices"].double().numpy(), subset)
    assert score == pytest.approx(pol[0]["polish_cm"])

    def v2v(o):
        return np.linalg.norm(o["vertices"].double().numpy() - crossed["vertices"], axis=1).mean() * 100

    assert v2v(pol[0]) < v2v(short[0]) - 0.2, (v2v(short[0]), v2v(pol[0]))
    assert pol[1]["taken"] in ("", "none") and "polish_cm" not in pol[1]


def test_a_refit_after_a_doubt_stays_uncertain():
    """The flag the fitter sets on a replaced fit that passes the check after the first one was doubted:
    uncertain (written), never refused, and its reason names the first doubt."""
    from arteq.fit.quality import REFUSE_FLAGS, describe_flags, verdict

    q = {
        "inlier_frac": 0.95,
        "coverage": 0.96,
        "rmse_in_cm": 1.0,
        "parts_covered": 20,
        "max_abs_beta": 1.0,
        "extent_m": 1.6,
        "flags": ["refitted"],
        "first_doubt": "the scan covers only 91% of the fitted body",
    }
    assert verdict(q["flags"]) == "uncertain" and "refitted" not in REFUSE_FLAGS
    assert (
        describe_flags(q)
        == "refitted after the first fit was doubted (the scan covers only 91% of the fitted body)"
    )


def test_the_fitter_uncrosses_a_crossed_scan_and_says_so(body, scene, tmp_path, tiny_net):
    """Through ``Fitter`` and ``fit_files``: a scan of crossed forearms, and a "network" that reads it the way
    the torso-frame sides do (the uncrossed pose, points labelled by the uncrossed mesh), is fitted crossed
    with the step and stays uncrossed without it; the npz, json and summary say which pair was swapped."""
    import json

    from arteq.fit.files import fit_files
    from fit_helpers import reading_of, write_tiny_checkpoint

    s, fit = scene
    crossed = _posed(
        body, swap_start(s["pose"], fit["global_rotmats"], fit["joints"], "forearms"), s["betas"], s["transl"]
    )
    g = torch.Generator().manual_seed(1)
    from arteq.geometry.sampling import sample_surface

    pts, _, _ = sample_surface(
        torch.as_tensor(crossed["vertices"], dtype=torch.float32), body.faces, 5000, g, noise_std=0.003
    )
    pts = pts.double().numpy()
    ckpt = write_tiny_checkpoint(tmp_path / "tiny.ckpt", tiny_net)

    # the "network" reads the scan the way the torso-frame sides do: the uncrossed pose and labels
    Uncrossed = reading_of(fit["vertices"], s["pose"], s["betas"], s["transl"])

    v2v = {}
    for on in (True, False):
        # every pair tried (the trigger is pairs_to_try's, tested above): this fit passes the check
        f = Uncrossed(
            ckpt=ckpt, device="cpu", anny=False, crossing=CrossingConfig(near_m=10.0) if on else False
        )
        out = tmp_path / f"fits_{on}"
        path = tmp_path / "crossed.npy"
        np.save(path, pts)
        summary = fit_files([path], out, fitter=f, preview=False, log=lambda m: None)
        z = np.load(out / "crossed.npz")
        v2v[on] = float(np.linalg.norm(z["vertices"] - crossed["vertices"], axis=1).mean() * 100)
        row = summary.rows[0]
        js = json.loads((out / "crossed.json").read_text())
        if on:
            assert str(z["crossing_taken"]) == "forearms" and row["crossing"] == "forearms", row
            assert js["crossing"]["taken"] == "forearms" and "none" in js["crossing"]["tried_cm"], js[
                "crossing"
            ]
        else:
            assert str(z["crossing_taken"]) == "" and row["crossing"] == "" and js["crossing"] is None
    assert v2v[True] < 1.5 < 3.0 < v2v[False], v2v


@pytest.mark.parametrize("b", [(0.3, -0.2, 0.9), (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (-0.6, 0.8, 0.0)])
def test_rotation_between_takes_a_to_b(b):
    """The one helper for "the smallest rotation from a to b" (swap_start, the Anny rig), opposite directions
    included."""
    from arteq.geometry.rotations import rotation_between

    a = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    b = torch.tensor(b, dtype=torch.float64)
    r = rotation_between(a, b)
    torch.testing.assert_close(r @ a, b / b.norm())
    torch.testing.assert_close(r @ r.T, torch.eye(3, dtype=torch.float64))
    assert torch.linalg.det(r) > 0.999
    axis = torch.linalg.cross(a, b)
    if axis.norm() > 1e-6:  # the smallest one: it keeps the common normal fixed
        torch.testing.assert_close(r @ axis, axis)
