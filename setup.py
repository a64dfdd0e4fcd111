"""Build hook; the project's metadata is in pyproject.toml.

The top-level ``conf/`` folder (the Hydra configs users read and edit in a checkout) ships inside the
wheel as ``arteq/conf/``, so that ``python -m arteq.train`` runs from a non-editable install in any folder.
:func:`arteq.paths.conf_dir` finds it there, or at the top of a checkout.
"""

from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


class BuildPyWithConf(build_py):
    """``build_py`` that also copies ``conf/**/*.yaml`` to ``<build>/arteq/conf/``."""

    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return  # an editable install reads the checkout's conf/ in place
        src = ROOT / "conf"
        if not (src / "train.yaml").is_file():
            raise SystemExit(f"setup.py: {src / 'train.yaml'} is missing: the wheel would have no configs")
        for f in sorted(src.rglob("*.yaml")):
            dest = Path(self.build_lib, "arteq", "conf", f.relative_to(src))
            self.mkpath(str(dest.parent))
            self.copy_file(str(f), str(dest))


setup(cmdclass={"build_py": BuildPyWithConf})
