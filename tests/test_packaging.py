"""The package as users install it: configs found in a checkout and inside an installed wheel, metadata.

The wheel test builds the wheel from a copy of the sources (the checkout is not written to), installs it
with ``--no-deps`` into a fresh venv that sees this interpreter's site-packages (for torch, Lightning...)
but not the checkout, and from another folder composes the stage-2 config through ``python -m arteq.train``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

import arteq.paths
from arteq.paths import conf_dir

ROOT = Path(__file__).resolve().parents[1]
#: What the wheel is built from (everything else in the checkout stays out of it).
SOURCES = ("src", "conf", "pyproject.toml", "setup.py", "MANIFEST.in", "README.md", "LICENSE",
           "CITATION.cff", "CHANGELOG.md")  # fmt: skip


def test_conf_dir_in_the_checkout_is_the_top_level_conf():
    assert conf_dir() == ROOT / "conf"
    assert (conf_dir() / "experiment" / "stage2.yaml").is_file()


def test_conf_dir_prefers_the_packaged_copy_and_names_what_it_tried(tmp_path, monkeypatch):
    site = tmp_path / "site-packages" / "arteq"  # an installed package: no src/ above it
    monkeypatch.setattr(arteq.paths, "_PACKAGE", site)
    with pytest.raises(FileNotFoundError, match="no config folder.*site-packages/arteq/conf"):
        conf_dir()
    (site / "conf").mkdir(parents=True)
    (site / "conf" / "train.yaml").write_text("seed: 1\n")
    assert conf_dir() == site / "conf"


def test_metadata_license_and_torch_range():
    tomllib = pytest.importorskip("tomllib")
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert meta["license"] == "Apache-2.0"
    assert "Apache License" in (ROOT / "LICENSE").read_text()[:200]
    torch_req = [d for d in meta["dependencies"] if d.split(">")[0].split("=")[0].strip() == "torch"]
    assert torch_req == ["torch>=2.4"], torch_req
    # make install pins the on-disk CPU build before the project (pip would otherwise pull a CUDA build)
    make = (ROOT / "Makefile").read_text()
    assert "TORCH ?= torch==2.13.0" in make
    assert make.index("pip install -q $(TORCH)") < make.index('pip install -q -e ".[anny,dev]"')


def test_citation_names_the_paper_and_its_authors():
    text = (ROOT / "CITATION.cff").read_text()
    assert "Generalizing Neural Human Fitting to Unseen Poses With Articulated SE(3) Equivariance" in text
    for family in ("Feng", "Kulits", "Liu", "Black", "Abrevaya"):
        assert f"family-names: {family}" in text


def _run(cmd: list[str], cwd: Path, **kw) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env.update(OMP_NUM_THREADS="1", PIP_NO_INPUT="1")
    out = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=600, **kw)
    assert out.returncode == 0, f"{' '.join(cmd)}\n{out.stdout[-3000:]}\n{out.stderr[-3000:]}"
    return out


def test_wheel_ships_conf_and_trains_from_any_folder(tmp_path):
    pytest.importorskip("setuptools")
    src = tmp_path / "source"
    src.mkdir()
    for name in SOURCES:
        p = ROOT / name
        if p.is_dir():
            shutil.copytree(p, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy2(p, src / name)
    wheels = tmp_path / "wheels"
    _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(wheels),
          str(src)], cwd=tmp_path)  # fmt: skip
    (wheel,) = wheels.glob("arteq-*.whl")

    import zipfile

    names = set(zipfile.ZipFile(wheel).namelist())
    conf = ROOT / "conf"
    shipped = {f"arteq/conf/{p.relative_to(conf).as_posix()}" for p in conf.rglob("*.yaml")}
    assert shipped <= names, sorted(shipped - names)[:5]
    assert "arteq/pretrained/anny22.ckpt" in names
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)

    # a fresh venv: this interpreter's site-packages for the dependencies (a .pth line is not scanned for
    # further .pth files, so the checkout's editable install stays out), the wheel installed --no-deps
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], cwd=tmp_path)
    py = venv / "bin" / "python"
    fresh_site = Path(_run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                           cwd=tmp_path).stdout.strip())  # fmt: skip
    (fresh_site / "parent_site.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    _run([str(py), "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(wheel)], cwd=tmp_path)

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    probe = "import arteq, arteq.paths; print(arteq.__file__); print(arteq.paths.conf_dir())"
    where = _run([str(py), "-c", probe], cwd=elsewhere).stdout.split()
    assert where[0].startswith(str(fresh_site)), where  # the installed copy, not the checkout
    assert where[1] == str(fresh_site / "arteq" / "conf")
    # compose (and print) the stage-2 config through the installed entry point; nothing is trained
    cmd = [str(py), "-m", "arteq.train", "--cfg", "job", "+experiment=stage2", "+scale=quick"]
    out = _run(cmd, cwd=elsewhere)
    assert "task_name: stage2" in out.stdout and "stage: 2" in out.stdout, out.stdout[-2000:]
    assert "max_epochs: 2" in out.stdout  # from conf/scale/quick.yaml, read from the wheel
    assert not (elsewhere / "outputs").exists()
