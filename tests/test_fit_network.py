"""arteq.fit without Lightning: the network loaded from the raw checkpoint (``arteq.fit.api.load_network``),
the same outputs as the LightningModule; the preview leaves matplotlib's backend alone.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from arteq.fit.api import Fitter, load_network
from conftest import subprocess_env
from fit_helpers import write_tiny_checkpoint


@pytest.fixture(scope="module")
def tiny_ckpt(tmp_path_factory, tiny_net):
    return write_tiny_checkpoint(tmp_path_factory.mktemp("ckpt") / "tiny.ckpt", tiny_net)


@pytest.fixture(scope="module")
def cloud(anny22, tmp_path_factory):
    from arteq.fit.demo import synthetic_scan

    s = synthetic_scan(anny22, "test_id", 0, 3000, offset=1.0)
    path = tmp_path_factory.mktemp("cloud") / "scan.npy"
    np.save(path, s["points"])
    return path


def test_network_without_lightning_matches_the_module(tiny_ckpt, cloud):
    """load_network rebuilds the network from ``hyper_parameters.net`` / ``body_model`` and its ``net.*``
    weights: outputs equal to the LightningModule's, bit for bit."""
    from arteq.training.module import ArtEqModule

    module = ArtEqModule.load_from_checkpoint(str(tiny_ckpt), map_location="cpu", weights_only=True).eval()
    net = load_network(tiny_ckpt)
    assert net.hparams["net"] == module.hparams["net"] and net.hparams.body_model["name"] == "anny22"
    x = torch.as_tensor(np.load(cloud)[:500] - np.load(cloud)[:500].mean(0), dtype=torch.float32)[None]
    with torch.no_grad():
        a, b = module(x), net(x)
    for key in ("part_probs", "local_rotmats", "betas", "transl"):
        assert torch.equal(a[key], b[key]), key


def test_fit_points_does_not_import_lightning(tiny_ckpt, cloud):
    """``import arteq.fit; fit_points(...)`` in a fresh interpreter: a fit, and Lightning never loaded."""
    code = (
        "import sys, numpy as np; import arteq.fit; from arteq.fit import fit_points; "
        f"r = fit_points(np.load({str(cloud)!r}), ckpt={str(tiny_ckpt)!r}, device='cpu', refine=False); "
        "print(r.status, r.vertices.shape[0]); "
        "print('lightning' in sys.modules, 'pytorch_lightning' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=subprocess_env())
    assert out.returncode == 0, out.stderr[-2000:]
    fit_line, mods = out.stdout.strip().splitlines()[-2:]
    assert fit_line.split()[1] == "13718", out.stdout
    assert mods == "False False", out.stdout


def test_not_a_checkpoint_is_named(tmp_path):
    bad = tmp_path / "weights.ckpt"
    torch.save({"model": {"w": torch.zeros(2)}}, bad)
    with pytest.raises(ValueError, match=r"weights\.ckpt: not an arteq checkpoint \(needs state_dict"):
        Fitter(ckpt=bad, device="cpu")


def test_preview_keeps_the_matplotlib_backend(tiny_ckpt, cloud, tmp_path):
    """render_preview draws on a figure of its own (Agg canvas): the caller's backend stays, pyplot is not
    imported, and the PNG is written."""
    png = tmp_path / "p.png"
    code = (
        "import sys, numpy as np, matplotlib; matplotlib.use('svg'); "
        "from arteq.fit.api import Fitter; from arteq.fit.preview import render_preview; "
        f"f = Fitter(ckpt={str(tiny_ckpt)!r}, device='cpu', refine=False, anny=False, check=False); "
        f"r = f.fit_points(np.load({str(cloud)!r})); render_preview(r, {str(png)!r}); "
        "print(matplotlib.get_backend(), 'matplotlib.pyplot' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=subprocess_env())
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "svg False", out.stdout
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_turned_reading_is_turned_back_into_the_clouds_frame(tiny_ckpt, cloud):
    """``FitNetwork(x, turn)``: the network reads the cloud turned and its answer comes back in the cloud's
    frame. Turned by an element of the network's rotation group, the answer is the unturned one (to float
    rounding: the network is equivariant to that group); turned by any rotation, the global rotations are
    those of the turned cloud's reading turned back, the per-point outputs the turned cloud's."""
    import roma

    from arteq.equivariant.group import group_rotations

    net = load_network(tiny_ckpt)
    pts = np.load(cloud)[:500]
    x = torch.as_tensor(pts - pts.mean(0), dtype=torch.float32)[None].repeat(2, 1, 1)
    group = group_rotations().float()[[7, 23]]
    torch.manual_seed(0)
    turn = roma.random_rotmat(2)
    with torch.no_grad():
        plain, in_group, turned = net(x), net(x, group), net(x, turn)
        raw = net(x @ turn.transpose(-1, -2))
    for key in ("local_rotmats", "global_rotmats", "transl", "part_probs", "betas"):
        assert torch.allclose(in_group[key], plain[key], atol=2e-3), key
    back = turn.transpose(-1, -2)[:, None]
    assert torch.allclose(turned["global_rotmats"], back @ raw["global_rotmats"], atol=1e-5)
    assert torch.allclose(turned["local_rotmats"][:, 1:], raw["local_rotmats"][:, 1:])
    assert torch.equal(turned["part_probs"], raw["part_probs"])
    assert not torch.allclose(turned["global_rotmats"], raw["global_rotmats"], atol=1e-2)  # it did turn back
