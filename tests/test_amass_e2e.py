"""``data=amass`` end to end on real-layout roots of both releases (tiny runs), and the one-line errors of
a bad root. The roots are written by the release writers of test_amass_layouts.py (no AMASS data)."""

from __future__ import annotations

import json
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse

from arteq.training.validate import ConfigError, ConfigPathError, validate_eval_config, validate_train_config
from conftest import compose_config
from test_amass_layouts import write_smplh_motion, write_smplh_release, write_smplx_release

WRITERS = {"smplh": write_smplh_release, "smplx": write_smplx_release}


def _eval_cfg(root: Path, *extra: str, ckpt: str = "anny22"):
    return compose_config([f"ckpt_path={ckpt}", "data=amass", f"data.amass_root={root}", *extra], "eval",
                          hydra_config=False)  # fmt: skip


def _one_line_error(root: Path, error: type) -> str:
    with pytest.raises(error) as e:
        validate_eval_config(_eval_cfg(root))
    msg = str(e.value)
    assert msg.startswith(f"data.amass_root='{root}': allowed: an AMASS root") and "\n" not in msg, msg
    return msg


def test_bad_roots_fail_in_one_line_naming_root_expected_and_found(tmp_path):
    root = write_smplx_release(tmp_path / "r")
    validate_eval_config(_eval_cfg(root))  # a complete root passes
    bad = root / "DFaust" / "50002" / "50002_hips_stageii.npz"
    np.savez(bad, poses=np.zeros((4, 165)), mocap_frame_rate=np.array(60.0))
    msg = _one_line_error(root, ConfigError)
    assert "50002_hips_stageii.npz: not an AMASS motion file, missing trans" in msg
    assert "found keys ['mocap_frame_rate', 'poses']" in msg
    bad.unlink()
    shutil.rmtree(root / "PosePrior")
    msg = _one_line_error(root, ConfigPathError)
    assert "no folder of sub-dataset PosePrior (expected one of ['PosePrior', 'MPI_Limits'])" in msg
    assert "found folders [DFaust]" in msg
    with pytest.raises(ConfigPathError, match=r"data\.amass_root='/no/such/amass': .*no such file or folder"):
        validate_eval_config(_eval_cfg(Path("/no/such/amass")))


def test_bad_amass_options_name_the_key(tmp_path):
    root = write_smplh_release(tmp_path / "r")
    for extra, key, allowed in [
        ("+data.amass.eval_stride=5", "data.amass.eval_stride=5", "(renamed) data.amass.eval_fps"),
        ("data.amass.train_fps=0", "data.amass.train_fps=0", "a target frame rate in Hz > 0"),
        ("data.amass.datasets=[DFaust,MPI_Limits]", "data.amass.datasets=['DFaust', 'MPI_Limits']",
         "['PosePrior'] would be both training data and the OOD test set"),
        ("+data.amass_ood_stride=5", "data.amass_ood_stride=5", "(renamed) data.amass.ood_fps"),
    ]:  # fmt: skip
        with pytest.raises(ConfigError) as e:
            validate_eval_config(_eval_cfg(root, extra))
        msg = str(e.value)
        assert msg.startswith(f"{key}: allowed: ") and allowed in msg and "\n" not in msg, msg
    with pytest.raises(ConfigPathError, match=r"no folder of sub-dataset CMU \(expected one of \['CMU'\]\)"):
        validate_eval_config(_eval_cfg(root, "data.amass.datasets=[DFaust,CMU]"))
    write_smplh_motion(root / "CMU" / "01" / "01_01_poses.npz", 10, 120.0, np.array("male"))
    validate_eval_config(_eval_cfg(root, "data.amass.datasets=[DFaust,CMU]"))


@pytest.mark.parametrize("release", ["smplh", "smplx"])
def test_train_stage2_then_eval_on_a_real_layout_root(tmp_path, release, tiny_config):
    from arteq.eval import evaluate
    from arteq.train import train

    root = WRITERS[release](tmp_path / "amass")
    write_smplh_motion(root / "CMU" / "01" / "01_01_poses.npz", 20, 120.0, np.array("male"))
    cfg = tiny_config("+experiment=stage2", "data=amass", f"data.amass_root={root}",
                      "data.amass.datasets=[DFaust,CMU]", f"paths.output_root={tmp_path}",
                      f"paths.output_dir={tmp_path / 'run'}")  # fmt: skip
    validate_train_config(cfg)
    s = train(cfg)
    assert s["stage1_init"]["how"] == "trained first in this run"
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())["metrics"]
    for split in ("test_id", "test_ood"):
        assert np.isfinite(metrics[split]["v2v_cm"]) and metrics[split]["v2v_cm"] > 0
    ev = tiny_config(f"ckpt_path={s['last_ckpt']}", "data=amass", f"data.amass_root={root}",
                     f"output_dir={tmp_path / 'ev'}", config_name="eval")  # fmt: skip
    validate_eval_config(ev)
    evaluate(ev)
    assert set(json.loads((tmp_path / "ev" / "metrics.json").read_text())["metrics"]) >= {
        "test_id",
        "test_ood",
    }


def write_smpl_file(path: Path) -> Path:
    """A synthetic SMPL-format file (``SMPL_NEUTRAL.pkl`` keys, 24 joints) on the toy body's mesh."""
    from arteq.body.skeleton import PARENTS
    from arteq.body.toy import ToyBody

    body = ToyBody(num_betas=10)
    V = body.v_template.shape[0]
    jr = body.J_regressor.double().numpy()
    d = {
        "v_template": body.v_template.double().numpy(),
        "shapedirs": 0.01 * np.random.default_rng(0).normal(size=(V, 3, 10)),
        "posedirs": np.zeros((V, 3, 207)),
        "J_regressor": scipy.sparse.csc_matrix(np.concatenate([jr, jr[[20, 21]]])),
        "weights": np.concatenate([body.lbs_weights.double().numpy(), np.zeros((V, 2))], 1),
        "kintree_table": np.array([[4294967295, *PARENTS[1:], 20, 21], list(range(24))], dtype=np.int64),
        "f": body.faces.numpy().astype(np.uint32),
        "bs_style": "lbs",
        "bs_type": "lrotmin",
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        pickle.dump(d, fh, protocol=2)
    return path


@pytest.mark.parametrize("release", ["smplh", "smplx"])
def test_train_with_an_smpl_body_file(tmp_path, release, tiny_config):
    from arteq.train import train

    root = WRITERS[release](tmp_path / "amass")
    smpl = write_smpl_file(tmp_path / "smpl" / "SMPL_NEUTRAL.pkl")
    cfg = tiny_config("+experiment=stage1", "data=amass", f"data.amass_root={root}", "body_model=smpl",
                      f"body_model.model_path={smpl}", f"paths.output_root={tmp_path}",
                      f"paths.output_dir={tmp_path / 'r'}")  # fmt: skip
    validate_train_config(cfg)
    s = train(cfg)
    assert np.isfinite(s["metrics"]["test_id"]["v2v_cm"])
