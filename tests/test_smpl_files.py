"""SMPL / SMPL+H model files as users have them, written synthetically with the real keys, dtypes, shapes
and pickle encodings (from public descriptions of the files; no model data):

- SMPL v1.0 ``basicModel_f_lbs_10_207_0_v1.0.0.pkl``: a Python 2 pickle (protocol 2, Python 2 module names,
  ``str`` payloads) of ``J_regressor_prior`` / ``J_regressor`` (``scipy.sparse.csc.csc_matrix [24, 6890]``),
  ``f`` (uint32), ``kintree_table`` (int64, root parent 4294967295), ``J``, ``weights_prior``,
  ``vert_sym_idxs``, ``pose_training_info`` (dict), ``bs_style`` / ``bs_type`` (str) and chumpy ``Ch`` objects
  for ``weights``, ``posedirs [6890, 3, 207]``, ``v_template`` and ``shapedirs [6890, 3, 10]``;
- SMPL v1.1 renamed for smplx (``SMPL_NEUTRAL.pkl``, ``SMPL_MALE.pkl``): the same with 300 shape components;
- SMPL+H: MANO's ``SMPLH_male.pkl`` (52 joints, ``posedirs [6890, 3, 459]``, hand PCA arrays) and AMASS's
  ``smplh/<gender>/model.npz`` (dense arrays, 16 shape components);
- chumpy-free conversions: smplx's cleaned ``.pkl`` (protocols 2-5) and ``np.savez`` of it (the sparse
  ``J_regressor`` becomes a pickled object entry).
"""

from __future__ import annotations

import io
import os
import pickle
import pickletools
import struct
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse
import torch

from arteq.body import BodyModelFileError, load_body_model
from arteq.body.skeleton import PARENTS
from arteq.body.smpl_io import read_model_file

V, F = 6890, 13776
ROOT_PARENT = 4294967295  # -1 as uint32, how the official files store the root's parent
SMPL_PARENTS = [*PARENTS, 20, 21]
# SMPL+H: 22 body joints, then 15 per hand (5 fingers x 3, each finger chained from its wrist)
SMPLH_PARENTS = [*PARENTS] + [
    p
    for wrist, first in ((20, 22), (21, 37))
    for f in range(5)
    for p in (wrist, first + 3 * f, first + 3 * f + 1)
]


# ---------------------------------------------------------------------------------------------- fakes
class Ch:
    """Stand-in for ``chumpy.ch.Ch`` when writing: pickles the state a real ``Ch`` pickles."""

    def __init__(self, x):
        self.x = np.asarray(x)

    def __getstate__(self):
        return {"x": self.x, "_dirty_vars": set(), "_itr": None, "_make_dense": False,
                "_make_sparse": False, "_depends_on_deps": {}}  # fmt: skip


class OldCsc:
    """Stand-in for Python 2 scipy's ``scipy.sparse.csc.csc_matrix`` when writing (its pickled state)."""

    def __init__(self, m):
        m = scipy.sparse.csc_matrix(m)
        self.state = {"_shape": m.shape, "maxprint": 50, "format": "csc", "data": m.data,
                      "indices": m.indices, "indptr": m.indptr}  # fmt: skip

    def __getstate__(self):
        return self.state


@pytest.fixture
def fake_modules(monkeypatch):
    """Register ``chumpy.ch`` and ``scipy.sparse.csc`` so that the writers pickle those names."""
    for mod, cls in (("chumpy.ch", Ch), ("scipy.sparse.csc", OldCsc)):
        m = types.ModuleType(mod)
        cls.__module__, cls.__qualname__ = mod, {"chumpy.ch": "Ch", "scipy.sparse.csc": "csc_matrix"}[mod]
        setattr(m, cls.__qualname__, cls)
        monkeypatch.setitem(sys.modules, mod, m)
    monkeypatch.setitem(sys.modules, "chumpy", types.ModuleType("chumpy"))
    yield
    Ch.__qualname__, OldCsc.__qualname__ = "Ch", "OldCsc"


class Py2Pickler(pickle._Pickler):
    """Writes what Python 2's ``cPickle.dump(obj, f, 2)`` wrote: ``str`` payloads (``BINSTRING``) for bytes
    and text, and Python 2 module names for numpy / scipy globals."""

    RENAME = {
        "numpy._core.multiarray": "numpy.core.multiarray",
        "builtins": "__builtin__",
        "copyreg": "copy_reg",
    }

    def save_bytes(self, obj):  # not memoized: small bytes objects are shared singletons
        self.write(pickle.BINSTRING + struct.pack("<i", len(obj)) + obj)

    def save_str(self, obj):
        self.save_bytes(obj.encode("latin1"))

    def save_global(self, obj, name=None):
        name = name or getattr(obj, "__qualname__", obj.__name__)
        module = pickle.whichmodule(obj, name)
        module = self.RENAME.get(module, module)
        self.write(pickle.GLOBAL + f"{module}\n{name}\n".encode())
        self.memoize(obj)

    dispatch = dict(pickle._Pickler.dispatch)
    dispatch[bytes] = save_bytes
    dispatch[str] = save_str


def _arrays(joints: int, parents: list[int], nb: int, npose: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    w = rng.random((V, joints)) ** 6
    w /= w.sum(1, keepdims=True)
    jr = scipy.sparse.random(joints, V, density=0.005, random_state=seed, format="csc")
    jr = scipy.sparse.csc_matrix(jr.multiply(1.0 / np.maximum(jr.sum(1), 1e-9)))
    return {
        "v_template": rng.normal(size=(V, 3)),
        "shapedirs": 0.01 * rng.normal(size=(V, 3, nb)),
        "posedirs": 0.001 * rng.normal(size=(V, 3, npose)),
        "J_regressor": jr,
        "weights": w,
        "kintree_table": np.array([[ROOT_PARENT, *parents[1:]], list(range(joints))], dtype=np.int64),
        "f": rng.integers(0, V, size=(F, 3)).astype(np.uint32),
    }


def smpl_v10_dict(arr: dict, gender: str) -> dict:
    """The dict of an official SMPL v1.0 / v1.1 ``.pkl`` (before chumpy is taken out)."""
    return {
        "J_regressor_prior": OldCsc(arr["J_regressor"]),
        "f": arr["f"],
        "J_regressor": OldCsc(arr["J_regressor"]),
        "kintree_table": arr["kintree_table"],
        "J": arr["J_regressor"] @ arr["v_template"],
        "weights_prior": arr["weights"],
        "weights": Ch(arr["weights"]),
        "vert_sym_idxs": np.arange(V, dtype=np.int64)[::-1].copy(),
        "posedirs": Ch(arr["posedirs"]),
        "pose_training_info": {
            "expid": "x",
            "J_regressor_prior_wt": 10.0,
            "restpose_type": "t",
            "bs_style": "lbs",
            "gender": gender,
            "bs_type": "lrotmin",
        },  # fmt: skip
        "bs_style": "lbs",
        "v_template": Ch(arr["v_template"]),
        "shapedirs": Ch(arr["shapedirs"]),
        "bs_type": "lrotmin",
    }


def _check(body, arr: dict, nb_keep: int) -> None:
    torch.testing.assert_close(body.v_template, torch.as_tensor(arr["v_template"], dtype=torch.float32))
    torch.testing.assert_close(body.shapedirs, torch.as_tensor(arr["shapedirs"][..., :nb_keep]).float())
    w = arr["weights"]
    parents = [-1, *arr["kintree_table"][0, 1:]]
    w22 = w[:, :22].copy()
    for j in range(22, w.shape[1]):  # hand / finger joints folded into their wrist
        a = j
        while a >= 22:
            a = parents[a]
        w22[:, a] += w[:, j]
    torch.testing.assert_close(body.lbs_weights, torch.as_tensor(w22).float())
    jr = arr["J_regressor"]
    jr = jr.toarray() if scipy.sparse.issparse(jr) else jr
    torch.testing.assert_close(body.J_regressor, torch.as_tensor(jr[:22]).float())
    pd = arr["posedirs"].reshape(V * 3, -1).T[:189]
    torch.testing.assert_close(body.posedirs, torch.as_tensor(pd).float())
    assert body.faces.dtype == torch.long and body.faces.shape == (F, 3)
    out = body(betas=torch.randn(2, nb_keep), pose=0.3 * torch.randn(2, 66))
    assert out.vertices.shape == (2, V, 3) and torch.isfinite(out.vertices).all()


@pytest.fixture(scope="module")
def smpl10():
    return _arrays(24, SMPL_PARENTS, 10, 207, seed=1)


# ---------------------------------------------------------------------------------------------- files
def test_smpl_v10_python2_pickle(tmp_path, fake_modules, smpl10):
    path = tmp_path / "basicModel_f_lbs_10_207_0_v1.0.0.pkl"
    with open(path, "wb") as fh:
        Py2Pickler(fh, protocol=2).dump(smpl_v10_dict(smpl10, "female"))
    raw = path.read_bytes()
    for name in (b"chumpy.ch\nCh", b"scipy.sparse.csc\ncsc_matrix", b"numpy.core.multiarray\n_reconstruct",
                 b"__builtin__\nset"):  # fmt: skip
        assert name in raw  # a pickle as Python 2 wrote it
    ops = {op.name for op, _, _ in pickletools.genops(raw)}
    assert "BINSTRING" in ops and not ops & {"SHORT_BINUNICODE", "BINUNICODE", "BINBYTES", "SHORT_BINBYTES"}
    for mod in ("chumpy", "chumpy.ch", "scipy.sparse.csc"):  # the loader needs neither chumpy nor old scipy
        sys.modules.pop(mod)
    _check(load_body_model("smpl", model_path=str(path), num_betas=10), smpl10, 10)


def test_smpl_v11_renamed_for_smplx_by_folder(tmp_path, fake_modules):
    models = tmp_path / "models" / "smpl"
    models.mkdir(parents=True)
    arrays = {}
    # the neutral model with 300 shape components, the gendered ones with 10 (both are distributed)
    for gender, name, nb in (("neutral", "SMPL_NEUTRAL.pkl", 300), ("male", "SMPL_MALE.pkl", 10),
                             ("female", "SMPL_FEMALE.pkl", 10)):  # fmt: skip
        arrays[gender] = _arrays(
            24, SMPL_PARENTS, nb, 207, seed={"neutral": 2, "male": 3, "female": 4}[gender]
        )
        d = smpl_v10_dict(arrays[gender], gender)
        d.pop("vert_sym_idxs")
        with open(models / name, "wb") as fh:
            pickle.dump(d, fh, protocol=2)
    for gender in ("neutral", "male", "female"):  # SMPL_MALE is not taken for female nor FEMALE for male
        body = load_body_model("smpl", model_path=str(tmp_path / "models"), gender=gender, num_betas=10)
        torch.testing.assert_close(body.v_template, torch.as_tensor(arrays[gender]["v_template"]).float())
    _check(load_body_model("smpl", model_path=str(models / "SMPL_NEUTRAL.pkl"), num_betas=300),
           arrays["neutral"], 300)  # fmt: skip


def test_smplh_mano_pickle(tmp_path, fake_modules):
    arr = _arrays(52, SMPLH_PARENTS, 10, 459, seed=5)
    d = smpl_v10_dict(arr, "male")
    for side in "lr":
        d[f"hands_components{side}"] = np.eye(45)
        d[f"hands_mean{side}"] = np.zeros(45)
        d[f"hands_coeffs{side}"] = np.zeros((1554, 45))
    path = tmp_path / "mano_v1_2" / "models" / "SMPLH_male.pkl"
    path.parent.mkdir(parents=True)
    with open(path, "wb") as fh:
        pickle.dump(d, fh, protocol=2)
    body = load_body_model("smplh", model_path=str(path), num_betas=10)
    _check(body, arr, 10)
    # every finger's skinning weight went to its wrist
    w = arr["weights"]
    np.testing.assert_allclose(
        body.lbs_weights[:, 20].double().numpy(), w[:, [20, *range(22, 37)]].sum(1), rtol=1e-5
    )


def test_smplh_amass_npz_by_folder(tmp_path):
    arr = _arrays(52, SMPLH_PARENTS, 16, 459, seed=6)
    for gender in ("male", "female"):
        d = {
            "J_regressor_prior": arr["J_regressor"].toarray()[:24],
            "f": arr["f"].astype(np.int32),
            "J_regressor": arr["J_regressor"].toarray(),
            "kintree_table": arr["kintree_table"],
            "J": arr["J_regressor"] @ arr["v_template"],
            "weights_prior": arr["weights"][:, :24],
            "weights": arr["weights"],
            "posedirs": arr["posedirs"],
            "bs_style": np.array("lbs"),
            "v_template": arr["v_template"] + (gender == "female"),
            "shapedirs": arr["shapedirs"],
            "bs_type": np.array("lrotmin"),
        }
        (tmp_path / "smplh" / gender).mkdir(parents=True)
        np.savez(tmp_path / "smplh" / gender / "model.npz", **d)
    body = load_body_model("smplh", model_path=str(tmp_path / "smplh"), gender="male", num_betas=16)
    _check(body, arr, 16)
    female = load_body_model("smplh", model_path=str(tmp_path / "smplh"), gender="female", num_betas=16)
    assert torch.allclose(female.v_template - body.v_template, torch.ones(()))


@pytest.mark.parametrize("protocol", [2, 4, 5])
def test_chumpy_free_pickle_of_smplx_tools(tmp_path, smpl10, protocol):
    d = {k: v for k, v in smpl10.items()}  # plain arrays, J_regressor still a scipy sparse matrix
    if protocol == 4:  # a conversion made with scipy's newer sparse arrays
        d["J_regressor"] = scipy.sparse.csc_array(d["J_regressor"])
    d |= {"bs_style": "lbs", "bs_type": "lrotmin", "J": smpl10["J_regressor"] @ smpl10["v_template"]}
    path = tmp_path / "SMPL_NEUTRAL.pkl"
    with open(path, "wb") as fh:
        pickle.dump(d, fh, protocol=protocol)
    _check(load_body_model("smpl", model_path=str(path), num_betas=10), smpl10, 10)


def test_npz_with_pickled_sparse_regressor(tmp_path, smpl10):
    path = tmp_path / "SMPL_NEUTRAL.npz"
    np.savez(path, **smpl10, bs_style="lbs", bs_type="lrotmin")  # J_regressor: a pickled object entry
    with np.load(path, allow_pickle=False) as z, pytest.raises(ValueError, match="allow_pickle"):
        z["J_regressor"]
    _check(load_body_model("smpl", model_path=str(path), num_betas=10), smpl10, 10)
    assert scipy.sparse.issparse(smpl10["J_regressor"])


class _Evil:
    def __reduce__(self):
        return (os.system, ("echo pwned > /dev/null",))


def test_npz_entry_that_runs_code_is_refused(tmp_path, smpl10):
    path = tmp_path / "SMPL_NEUTRAL.npz"
    np.savez(path, **{**smpl10, "J_regressor": np.array(_Evil(), dtype=object)})
    with pytest.raises(
        pickle.UnpicklingError, match=r"SMPL_NEUTRAL\.npz\['J_regressor'\]: refusing .*system"
    ):
        read_model_file(path)


# ---------------------------------------------------------------------------------------------- errors
def test_wrong_files_are_named(tmp_path, smpl10):
    # an AMASS motion file given as the body model
    motion = tmp_path / "50002_chicken_wings_poses.npz"
    np.savez(motion, poses=np.zeros((3, 156)), trans=np.zeros((3, 3)), betas=np.zeros(16))
    with pytest.raises(
        BodyModelFileError, match=r"chicken_wings_poses\.npz' lacks the SMPL model keys .*has "
    ):
        load_body_model("smpl", model_path=str(motion))
    # a MANO hand (778 vertices, 16 joints)
    rng = np.random.default_rng(0)
    mano = {
        "v_template": rng.normal(size=(778, 3)), "shapedirs": rng.normal(size=(778, 3, 10)),
        "posedirs": rng.normal(size=(778, 3, 135)), "weights": np.full((778, 16), 1 / 16),
        "J_regressor": scipy.sparse.csc_matrix(np.full((16, 778), 1 / 778)),
        "kintree_table": np.array([[ROOT_PARENT, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14],
                                   list(range(16))]),
        "f": rng.integers(0, 778, (1538, 3)).astype(np.uint32), "hands_components": np.eye(45),
    }  # fmt: skip
    path = tmp_path / "MANO_RIGHT.pkl"
    with open(path, "wb") as fh:
        pickle.dump(mano, fh, protocol=2)
    with pytest.raises(
        BodyModelFileError, match=r"MANO_RIGHT\.pkl': kintree_table must be \[2, J>=22\], got \[2, 16\]"
    ):
        load_body_model("smpl", model_path=str(path))
    # a pickle that is not a dict, an npz saved as .pkl, another extension
    (tmp_path / "list.pkl").write_bytes(pickle.dumps([1, 2, 3], protocol=2))
    with pytest.raises(BodyModelFileError, match=r"list\.pkl': expected a pickled dict, got list"):
        load_body_model("smpl", model_path=str(tmp_path / "list.pkl"))
    buf = io.BytesIO()
    np.savez(buf, v_template=np.zeros((3, 3)))
    (tmp_path / "SMPL_MALE.pkl").write_bytes(buf.getvalue())
    with pytest.raises(BodyModelFileError, match=r"SMPL_MALE\.pkl' is not a readable SMPL-format model file"):
        load_body_model("smpl", model_path=str(tmp_path / "SMPL_MALE.pkl"))
    (tmp_path / "smpl.obj").write_text("v 0 0 0\n")
    with pytest.raises(BodyModelFileError, match=r"smpl\.obj': unsupported extension '\.obj'"):
        load_body_model("smpl", model_path=str(tmp_path / "smpl.obj"))
    # absent: the file, or a folder without a file for the gender
    with pytest.raises(BodyModelFileError, match=r"not found: '.*SMPL_NEUTRAL\.pkl'.*smpl\.is\.tue\.mpg\.de"):
        load_body_model("smpl", model_path=str(tmp_path / "none" / "SMPL_NEUTRAL.pkl"))
    empty = Path(tmp_path / "empty")
    empty.mkdir()
    with pytest.raises(BodyModelFileError, match=r"no neutral smpl model file .* under '.*empty'"):
        load_body_model("smpl", model_path=str(empty))
