"""SMPL / SMPL-H file loaders: npz and chumpy-style pkl round trips, unsafe pickles refused, clear errors."""

from __future__ import annotations

import os
import pickle
import sys
import types

import numpy as np
import pytest
import scipy.sparse
import torch

from arteq.body import BodyModelFileError, load_body_model
from arteq.body.skeleton import PARENTS

V, J = 6890, 24
SMPL_PARENTS = list(PARENTS) + [20, 21]


class Ch:
    """Fake ``chumpy.ch.Ch`` (registered as module ``chumpy.ch``) to write realistic SMPL pickles."""

    def __init__(self, x):
        self.x = np.asarray(x)

    def __getstate__(self):
        return {"x": self.x, "_dirty_vars": set(), "_itr": None}


@pytest.fixture
def fake_chumpy(monkeypatch):
    chumpy = types.ModuleType("chumpy")
    ch = types.ModuleType("chumpy.ch")
    Ch.__module__ = "chumpy.ch"
    ch.Ch = Ch
    chumpy.ch = ch
    monkeypatch.setitem(sys.modules, "chumpy", chumpy)
    monkeypatch.setitem(sys.modules, "chumpy.ch", ch)
    return Ch


def _smpl_arrays(nb: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    w = rng.random((V, J)) ** 6
    w /= w.sum(1, keepdims=True)
    jr = scipy.sparse.random(J, V, density=0.01, random_state=seed, format="csc")
    jr = scipy.sparse.csc_matrix(jr.multiply(1.0 / np.maximum(jr.sum(1), 1e-9)))
    kintree = np.array([[4294967295] + SMPL_PARENTS[1:], list(range(J))], dtype=np.int64)
    return {
        "v_template": rng.normal(size=(V, 3)),
        "shapedirs": 0.01 * rng.normal(size=(V, 3, nb)),
        "posedirs": 0.001 * rng.normal(size=(V, 3, 207)),
        "J_regressor": jr,
        "weights": w,
        "kintree_table": kintree,
        "f": rng.integers(0, V, size=(13776, 3)).astype(np.uint32),
    }


def _check_loaded(body, arr, nb_keep):
    torch.testing.assert_close(body.v_template, torch.as_tensor(arr["v_template"], dtype=torch.float32))
    assert body.num_betas == nb_keep and body.shapedirs.shape == (V, 3, nb_keep)
    torch.testing.assert_close(body.shapedirs, torch.as_tensor(arr["shapedirs"][..., :nb_keep]).float())
    w = arr["weights"]
    w22 = w[:, :22].copy()
    w22[:, 20] += w[:, 22]
    w22[:, 21] += w[:, 23]
    torch.testing.assert_close(body.lbs_weights, torch.as_tensor(w22).float())
    torch.testing.assert_close(body.J_regressor, torch.as_tensor(arr["J_regressor"].toarray()[:22]).float())
    pd = arr["posedirs"].reshape(V * 3, 207).T[:189]
    torch.testing.assert_close(body.posedirs, torch.as_tensor(pd).float())
    assert body.faces.dtype == torch.long and body.faces.shape == (13776, 3)
    assert body.part_labels.max() <= 21
    out = body(betas=torch.randn(2, nb_keep), pose=0.3 * torch.randn(2, 66))
    assert out.vertices.shape == (2, V, 3) and torch.isfinite(out.vertices).all()


@pytest.mark.parametrize("nb", [10, 300])
def test_npz_round_trip(tmp_path, nb):
    arr = _smpl_arrays(nb)
    path = tmp_path / "SMPL_NEUTRAL.npz"
    np.savez(path, **{k: (v.toarray() if scipy.sparse.issparse(v) else v) for k, v in arr.items()})
    body = load_body_model("smpl", model_path=str(path), num_betas=10)
    _check_loaded(body, arr, 10)
    # a folder is searched for the gendered file
    assert load_body_model("smpl", model_path=str(tmp_path), gender="neutral").num_vertices == V


def test_chumpy_pickle_round_trip(tmp_path, fake_chumpy):
    arr = _smpl_arrays(10, seed=1)
    data = dict(arr)
    data["shapedirs"] = fake_chumpy(arr["shapedirs"])
    data["v_template"] = fake_chumpy(arr["v_template"])
    data["weights"] = fake_chumpy(arr["weights"])
    data["bs_style"] = "lbs"
    data["bs_type"] = "lrotmin"
    path = tmp_path / "basicmodel_neutral_lbs_10_207_0_v1.1.0.pkl"
    with open(path, "wb") as fh:
        pickle.dump(data, fh, protocol=2)
    raw = open(path, "rb").read()
    assert b"chumpy.ch" in raw and b"csc_matrix" in raw  # a realistic pickle
    sys.modules.pop("chumpy.ch")  # the loader must not need chumpy
    sys.modules.pop("chumpy")
    body = load_body_model("smpl", model_path=str(path), num_betas=10)
    _check_loaded(body, arr, 10)


class _Evil:
    def __reduce__(self):
        return (os.system, ("echo pwned > /dev/null",))


def test_pickle_that_runs_code_is_refused(tmp_path):
    arr = _smpl_arrays(10)
    arr["v_template"] = _Evil()
    path = tmp_path / "SMPL_NEUTRAL.pkl"
    with open(path, "wb") as fh:
        pickle.dump(arr, fh, protocol=2)
    with pytest.raises(pickle.UnpicklingError, match=r"refusing to load global '(posix|os|nt)\.system'"):
        load_body_model("smpl", model_path=str(path))


def test_missing_and_malformed_files_give_clear_errors(tmp_path):
    missing = tmp_path / "nope" / "SMPL_NEUTRAL.pkl"
    with pytest.raises(BodyModelFileError, match="not found") as exc:
        load_body_model("smpl", model_path=str(missing))
    msg = str(exc.value)
    assert str(missing) in msg and "smpl.is.tue.mpg.de" in msg and "body_model.model_path" in msg
    with pytest.raises(BodyModelFileError, match="body_model.model_path"):
        load_body_model("smpl", model_path=None)
    garbage = tmp_path / "SMPL_MALE.npz"
    garbage.write_bytes(b"this is not a zip file")
    with pytest.raises(BodyModelFileError, match="SMPL_MALE.npz"):
        load_body_model("smpl", model_path=str(garbage))
    partial = tmp_path / "partial.npz"
    np.savez(partial, v_template=np.zeros((V, 3)))
    with pytest.raises(BodyModelFileError, match="lacks the SMPL model keys"):
        load_body_model("smpl", model_path=str(partial))
    arr = _smpl_arrays(10)
    arr["J_regressor"] = arr["J_regressor"].toarray()[:, :100]
    bad = tmp_path / "bad_shape.npz"
    np.savez(bad, **arr)
    with pytest.raises(BodyModelFileError, match="J_regressor must be"):
        load_body_model("smpl", model_path=str(bad))
    with pytest.raises(ValueError, match="betas"):
        load_body_model("smpl", model_path=str(_write(tmp_path)), num_betas=20)


def _write(tmp_path):
    arr = _smpl_arrays(10)
    path = tmp_path / "ok.npz"
    np.savez(path, **{k: (v.toarray() if scipy.sparse.issparse(v) else v) for k, v in arr.items()})
    return path
